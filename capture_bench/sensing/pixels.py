"""Pixels of the eye-to-hand camera: where eq. 2's image-plane point lands in the image, and the
exact image of a sphere marker.

Pixel convention (the rendered image, `capture_bench.sensing.render_camera.render_frame`,
and the detector, `capture_bench.sensing.detector`):

* An image is an array ``(height, width, 3)``: row ``v`` 0 at the top, column ``u`` 0 at the left,
  as numpy and OpenCV store it. Continuous pixel coordinates ``(u, v)`` are OpenCV's: integer
  values are pixel *centres*, so the sensor spans ``[-0.5, width - 0.5] x [-0.5, height - 0.5]``
  and its centre (the principal point) is ``((width - 1) / 2, (height - 1) / 2)``.
* Eq. 2 gives ``(x_m, z_m)`` on the image plane behind the lens, where the real image is
  inverted (``x_m = -f x_C / (y_C - f)``). The image is read out upright, as a viewer at the lens
  looking along the camera's +y axis with +z up sees the scene: camera +x is to the right
  (``u`` grows), camera +z is up (``v`` falls). Hence

      u = (width - 1) / 2 - x_m / pitch,      v = (height - 1) / 2 + z_m / pitch.

  The image-plane edges ``|x_m| = width pitch / 2`` are the sensor's outer pixel edges, so
  `on_sensor` and this mapping agree.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.camera_model import CameraModel, project_points

FloatArray = NDArray[np.float64]


def principal_point(model: CameraModel) -> FloatArray:
    """The image centre ``((width - 1) / 2, (height - 1) / 2)``, pixels, shape (2,)."""
    width, height = model.resolution
    return np.array([(width - 1) / 2.0, (height - 1) / 2.0])


def image_plane_to_pixel(image_points: ArrayLike, model: CameraModel) -> FloatArray:
    """Eq. 2's image-plane points ``[x_m, z_m]`` (metres, (N, 2)) -> pixels ``[u, v]`` (N, 2):
    ``u = (width - 1)/2 - x_m/pitch``, ``v = (height - 1)/2 + z_m/pitch`` (module docstring)."""
    m = np.asarray(image_points, dtype=float)
    centre = principal_point(model)
    pitch = model.pixel_pitch
    return np.column_stack([centre[0] - m[:, 0] / pitch, centre[1] + m[:, 1] / pitch])


def pixel_to_image_plane(pixels: ArrayLike, model: CameraModel) -> FloatArray:
    """Pixels ``[u, v]`` (N, 2) -> image-plane points ``[x_m, z_m]`` (metres, (N, 2)); the
    inverse of `image_plane_to_pixel`."""
    p = np.asarray(pixels, dtype=float)
    centre = principal_point(model)
    return np.column_stack([centre[0] - p[:, 0], p[:, 1] - centre[1]]) * model.pixel_pitch


def pixel_of(points_cam: ArrayLike, model: CameraModel) -> FloatArray:
    """Camera-frame points (metres, (N, 3)) -> pixels ``[u, v]`` (N, 2): eq. 2, then
    `image_plane_to_pixel`. Meaningless for points not beyond the lens
    (`in_front`)."""
    return image_plane_to_pixel(project_points(points_cam, model.focal_length), model)


def pixel_to_global(pixels: ArrayLike, depth: ArrayLike, model: CameraModel) -> FloatArray:
    """The global points (metres, (N, 3)) seen at pixels ``[u, v]`` (N, 2) at ``depth`` (N,),
    metres beyond the lens along the camera's y-axis (``y_C - f``): the inverse of eq. 2 for a
    known depth. Used to place things where the camera sees them."""
    m = pixel_to_image_plane(pixels, model)
    d = np.asarray(depth, dtype=float)
    scale = -d / model.focal_length  # eq. 2 solved for x_C, z_C
    points_cam = np.column_stack([m[:, 0] * scale, d + model.focal_length, m[:, 1] * scale])
    return model.to_global(points_cam)


class SphereImage(NamedTuple):
    """The ellipses that spheres project to (`sphere_image`); NaN for a sphere not wholly
    beyond the lens.

    Attributes:
        centre: ellipse centres ``[u, v]``, pixels, shape (N, 2).
        area: ellipse areas, pixels^2, shape (N,).
        semi_major: longest semi-axes, pixels, shape (N,).
    """

    centre: FloatArray
    area: FloatArray
    semi_major: FloatArray


def sphere_image(centres_cam: ArrayLike, radius: float, model: CameraModel) -> SphereImage:
    """Centre and area of the exact image of spheres: what an unoccluded, ideally rendered sphere
    marker covers on the sensor.

    A sphere's image under eq. 2 is an ellipse, the section of the cone of rays from the lens
    tangent to the sphere. Off the optical axis that ellipse's centre (which is its area centroid)
    lies further out than the projection of the sphere's centre, by about
    ``r_px (R / D)^2 / cos^2(alpha)`` pixels for a centre ``r_px`` pixels from the principal point,
    at distance ``D`` from the lens and angle ``alpha`` off the axis (0.06 px at the sensor's
    corner for R = 0.01 m at D = 1.2 m with the default camera).

    With ``d = (x_C, y_C - f, z_C)`` the lens-to-centre vector and ``(a, b) = (d_x, d_z) / d_y``
    the ray through a pixel, a ray lies inside the cone when
    ``(g . (a, b, 1))^2 - (|d|^2 - R^2)(a^2 + b^2 + 1) >= 0`` with ``g = (d_x, d_z, d_y)``; the
    conic's centre and area follow from its 3 x 3 matrix ``g g^T - (|d|^2 - R^2) I``, and pixels
    are ``u = u_0 + (f/pitch) a``, ``v = v_0 - (f/pitch) b`` (eq. 2 and
    `image_plane_to_pixel`).

    Args:
        centres_cam: sphere centres in the camera frame, metres, shape (N, 3).
        radius: sphere radius R, metres.
        model: the camera.

    Returns:
        `SphereImage` ``(centre, area, semi_major)``; NaN for a sphere not wholly beyond
        the lens (``y_C - f <= R``), whose image is unbounded.
    """
    c = np.asarray(centres_cam, dtype=float).reshape(-1, 3)
    d = c - np.array([0.0, model.focal_length, 0.0])
    g = d[:, [0, 2, 1]]  # (d_x, d_z, d_y): the ray (a, b, 1) is d / d_y
    k = np.einsum("ni,ni->n", d, d) - radius**2
    conic = g[:, :, None] * g[:, None, :] - k[:, None, None] * np.eye(3)
    p, q, s = conic[:, 0, 0], conic[:, 0, 1], conic[:, 1, 1]  # A = [[p, q], [q, s]]
    b2 = conic[:, :2, 2]
    det = np.where(d[:, 1] > radius, p * s - q * q, np.nan)
    inv = np.stack([np.stack([s, -q], -1), np.stack([-q, p], -1)], -2) / det[:, None, None]
    centre_ab = -np.einsum("nij,nj->ni", inv, b2)
    # (X - X0)^T A (X - X0) + c0 >= 0 with A negative definite: an ellipse of area pi c0/sqrt(det A)
    c0 = conic[:, 2, 2] + np.einsum("ni,ni->n", b2, centre_ab)
    area_ab = np.pi * c0 / np.sqrt(det)
    # A's eigenvalues are R^2 - d_y^2 (along (d_x, d_z)) and -k: semi-axes sqrt(c0 / |eigenvalue|)
    semi_major_ab = np.sqrt(c0 / (d[:, 1] ** 2 - radius**2))
    scale = model.focal_length / model.pixel_pitch
    u0, v0 = principal_point(model)
    centres = np.column_stack([u0 + scale * centre_ab[:, 0], v0 - scale * centre_ab[:, 1]])
    return SphereImage(centres, area_ab * scale**2, semi_major_ab * scale)
