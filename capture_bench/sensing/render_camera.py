"""pybullet's view of the eye-to-hand camera: view and projection matrices from a
`CameraModel`, and rendering a frame or a window of one.

The rendered image is the upright image of `capture_bench.sensing.pixels` (its pixel
convention): a point whose eq. 2 projection falls at pixel ``(u, v)`` is drawn at column ``u``,
row ``v``.

* **Eye**: the centre of projection of eq. 2 is the lens, ``position + f R_gc[:, 1]`` (global, m):
  the ray from a point through the lens meets the image plane ``y = 0`` at eq. 2's ``(x_m, z_m)``.
* **View matrix** (OpenGL's lookAt): the eye looks along the camera's +y axis with the camera's +z
  axis up, so eye coordinates are ``(x_C, z_C, -(y_C - f))``.
* **Projection matrix** (OpenGL's frustum): the virtual, upright image at distance f in front of
  the lens has the sensor's size, so the vertical field of view is ``2 atan(h pitch / 2 f)`` and
  the aspect ``w / h`` (square pixels). A window ``[u0, u1) x [v0, v1)`` of the sensor is the
  off-centre frustum through those pixels' edges, rendered at the same pixel density, so its
  pixels are the full frame's.
* **Sampling**: pybullet's TinyRenderer shades each pixel with the scene at the pixel's lower-left
  corner in OpenGL window coordinates (its integer raster coordinate), not at its centre. The
  frustum is shifted by ``TINY_RENDERER_SAMPLE_OFFSET`` = 0.5 pixel right and up so that pixel
  ``(u, v)`` shows the scene at the centre of pixel ``(u, v)`` of
  `pixels`. Without the shift the image is off by half a pixel in
  ``u`` and in ``v``.
* **Scaled windows**: a window of ``s w x s h`` sensor pixels (s a whole number) can be rendered
  directly at ``w x h`` (`render_frame`'s ``size``): the frustum is the window's, shifted by
  half an *image* pixel, so image pixel ``(i, j)`` (row, column) shows the scene at the centre of
  its ``s x s`` block of sensor pixels, which for odd s is the centre of the window's
  full-density pixel ``(s i + s // 2, s j + s // 2)``.

Matrices are column-major 16-tuples, as ``computeViewMatrix`` and ``computeProjectionMatrixFOV``
return them and ``getCameraImage`` takes them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench._quiet import quiet_c_output
from capture_bench.sensing.camera import CameraModel

with quiet_c_output():  # pybullet prints its build time on import
    import pybullet
    from pybullet_utils.bullet_client import BulletClient

Matrix16 = tuple[float, ...]  # a 4 x 4 matrix, column-major
Window = tuple[int, int, int, int]  # (u0, u1, v0, v1): columns u0..u1-1, rows v0..v1-1, pixels

# Clipping planes, metres from the lens along the camera's y-axis. The default camera is ~1.2 m
# from the workspace, the arm reaches 0.9 m from its base: everything of interest is 0.05-5 m away.
NEAR_PLANE = 0.05
FAR_PLANE = 5.0
TINY_RENDERER_SAMPLE_OFFSET = 0.5  # pixels: where TinyRenderer samples a pixel, from its corner


def lens_position(model: CameraModel) -> NDArray[np.float64]:
    """The lens (eq. 2's centre of projection) in the global frame, metres, shape (3,):
    ``position + f R_gc[:, 1]``."""
    return model.position + model.focal_length * model.rotation[:, 1]


def vertical_fov(model: CameraModel) -> float:
    """Vertical field of view ``2 atan(h pitch / 2 f)``, radians (h: sensor height, pixels)."""
    return 2.0 * math.atan(model.resolution[1] * model.pixel_pitch / (2.0 * model.focal_length))


def _column_major(m: NDArray[np.float64]) -> Matrix16:
    return tuple(float(v) for v in m.T.ravel())


def view_matrix(model: CameraModel) -> Matrix16:
    """OpenGL view matrix (global -> eye coordinates) of the camera: eye at the lens, looking
    along the camera's +y axis, up = the camera's +z axis; what
    ``computeViewMatrix(lens, lens + y_axis, z_axis)`` returns, in double precision.

    Returns:
        The 4 x 4 matrix, column-major, 16 floats; its rows are ``(x_axis, -x . lens)``,
        ``(z_axis, -z . lens)``, ``(-y_axis, y . lens)``, ``(0, 0, 0, 1)``.
    """
    x_axis, y_axis, z_axis = model.rotation.T
    eye = lens_position(model)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = x_axis, z_axis, -y_axis
    m[:3, 3] = -m[:3, :3] @ eye
    return _column_major(m)


def frustum_matrix(
    left: float, right: float, bottom: float, top: float, near: float, far: float
) -> Matrix16:
    """OpenGL's perspective frustum (``glFrustum``): ``left..right``, ``bottom..top`` are the
    window's edges on the near plane (eye coordinates, metres), ``near``/``far`` the clipping
    distances (metres, 0 < near < far). Column-major, 16 floats."""
    if not 0.0 < near < far:
        raise ValueError(f"need 0 < near < far, got near={near}, far={far}")
    m = np.zeros((4, 4))
    m[0, 0] = 2.0 * near / (right - left)
    m[0, 2] = (right + left) / (right - left)
    m[1, 1] = 2.0 * near / (top - bottom)
    m[1, 2] = (top + bottom) / (top - bottom)
    m[2, 2] = -(far + near) / (far - near)
    m[2, 3] = -2.0 * far * near / (far - near)
    m[3, 2] = -1.0
    return _column_major(m)


def check_window(window: Window | None, model: CameraModel) -> Window:
    """The window as four ints, the full sensor for None; raises ValueError unless
    ``0 <= u0 < u1 <= width`` and ``0 <= v0 < v1 <= height``."""
    width, height = model.resolution
    if window is None:
        return (0, width, 0, height)
    u0, u1, v0, v1 = (int(v) for v in window)
    if not (0 <= u0 < u1 <= width and 0 <= v0 < v1 <= height):
        raise ValueError(
            f"window (u0, u1, v0, v1) = {window} must satisfy 0 <= u0 < u1 <= {width} and "
            f"0 <= v0 < v1 <= {height} (pixels of the {width} x {height} sensor)"
        )
    return (u0, u1, v0, v1)


def projection_matrix(
    model: CameraModel,
    window: Window | None = None,
    near: float = NEAR_PLANE,
    far: float = FAR_PLANE,
    sample_offset: float = TINY_RENDERER_SAMPLE_OFFSET,
) -> Matrix16:
    """OpenGL projection matrix of the sensor, or of a window of it at full pixel density.

    The virtual image at distance f in front of the lens spans ``(u - w/2) pitch`` across for
    pixel-edge coordinate ``u`` (0 at the left edge of column 0) and ``(h/2 - v) pitch`` up for
    row-edge coordinate ``v`` (0 at the top of row 0); the window's frustum passes through its
    edges ``u0, u1, v0, v1``, shifted by ``sample_offset`` pixels right and up.

    Args:
        model: the camera.
        window: ``(u0, u1, v0, v1)``: columns ``u0 .. u1-1`` and rows ``v0 .. v1-1`` of the full
            sensor, pixels; None for the whole sensor.
        near, far: clipping distances from the lens, metres.
        sample_offset: how far the renderer's sample point lies left of and below each pixel's
            centre, pixels (0.5 for TinyRenderer, which samples the lower-left corner); the
            frustum is shifted by as much right and up. With 0 and no window the matrix is
            ``computeProjectionMatrixFOV(degrees(vertical_fov), w / h, near, far)``.

    Returns:
        The 4 x 4 matrix, column-major, 16 floats.
    """
    u0, u1, v0, v1 = check_window(window, model)
    width, height = model.resolution
    scale = near * model.pixel_pitch / model.focal_length  # metres on the near plane per pixel
    return frustum_matrix(
        (u0 - width / 2.0 + sample_offset) * scale,
        (u1 - width / 2.0 + sample_offset) * scale,
        (height / 2.0 - v1 + sample_offset) * scale,
        (height / 2.0 - v0 + sample_offset) * scale,
        near,
        far,
    )


@dataclass(frozen=True)
class Lighting:
    """pybullet's single directional light for `render_frame` (``getCameraImage``'s light
    arguments). The defaults light the scene flatly, without specular highlights (which would
    whiten the markers) or shadows.

    Attributes:
        source: where the light is, global, metres, shape (3,); pybullet lights along the
            direction from there to the global origin (``lightDirection``). None: at the lens.
        colour: RGB of the light, each in [0, 1] (``lightColor``).
        distance: distance of the light for the shadow map, metres (``lightDistance``).
        ambient, diffuse, specular: the shading coefficients (``lightAmbientCoeff``,
            ``lightDiffuseCoeff``, ``lightSpecularCoeff``).
        shadow: whether objects cast shadows (``shadow``).
    """

    source: tuple[float, float, float] | None = None
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    distance: float = 2.0
    ambient: float = 0.6
    diffuse: float = 0.4
    specular: float = 0.0
    shadow: bool = False


def window_scale(window: Window, size: tuple[int, int]) -> int:
    """How many sensor pixels a side of an image pixel spans when ``window`` ``(u0, u1, v0, v1)``
    is rendered at ``size`` ``(width, height)``: the whole number s with ``u1 - u0 = s width``
    and ``v1 - v0 = s height``; ``ValueError`` if there is none."""
    u0, u1, v0, v1 = window
    width, height = int(size[0]), int(size[1])
    s = (u1 - u0) // width if width >= 1 else 0
    if s < 1 or (u1 - u0, v1 - v0) != (s * width, s * height):
        raise ValueError(
            f"window {window} is not a whole number of times the size {size} on both axes"
        )
    return s


def render_frame(
    bullet: BulletClient,
    model: CameraModel,
    window: Window | None = None,
    lighting: Lighting | None = None,
    near: float = NEAR_PLANE,
    far: float = FAR_PLANE,
    size: tuple[int, int] | None = None,
) -> NDArray[np.uint8]:
    """What the camera sees: the scene in ``bullet`` rendered by TinyRenderer (no GL needed).

    Args:
        bullet: the client holding the scene.
        model: the camera (pose, f, pitch, resolution).
        window: ``(u0, u1, v0, v1)``, pixels of the full sensor (`projection_matrix`);
            None for the full frame.
        lighting: the light; None for ``Lighting()``.
        near, far: clipping distances from the lens, metres.
        size: ``(width, height)`` to render the window at, pixels, the window being s times
            that on both axes (`window_scale`; module docstring, scaled windows); None:
            full pixel density (s = 1).

    Returns:
        RGB image, uint8, shape ``(v1 - v0, u1 - u0, 3)`` (``(height, width, 3)`` for the full
        frame); its pixel ``[i, j]`` is the full frame's pixel ``[v0 + i, u0 + j]``. With
        ``size``: shape ``(height, width, 3)``, pixel ``[i, j]`` sampled at the centre of the
        full frame's pixels ``[v0 + s i .. v0 + s i + s - 1, u0 + s j .. u0 + s j + s - 1]``.
    """
    request = camera_image_request(model, window, lighting, near, far, size)
    width, height = request["width"], request["height"]
    _, _, rgba, _, _ = bullet.getCameraImage(**request)
    return np.ascontiguousarray(np.reshape(rgba, (height, width, 4))[..., :3], dtype=np.uint8)


def camera_image_request(
    model: CameraModel,
    window: Window | None = None,
    lighting: Lighting | None = None,
    near: float = NEAR_PLANE,
    far: float = FAR_PLANE,
    size: tuple[int, int] | None = None,
) -> dict[str, Any]:
    """The keyword arguments of ``getCameraImage`` with which `render_frame` renders (its
    arguments, the same meaning): computed once where many frames of one view are rendered.
    ``width`` and ``height`` are the image's, pixels; the buffer comes back RGBA."""
    u0, u1, v0, v1 = check_window(window, model)
    light = Lighting() if lighting is None else lighting
    source = lens_position(model) if light.source is None else np.asarray(light.source, float)
    width, height = (u1 - u0, v1 - v0) if size is None else (int(size[0]), int(size[1]))
    s = 1 if size is None else window_scale((u0, u1, v0, v1), (width, height))
    offset = TINY_RENDERER_SAMPLE_OFFSET * s
    return {
        "width": width,
        "height": height,
        "viewMatrix": view_matrix(model),
        "projectionMatrix": projection_matrix(model, (u0, u1, v0, v1), near, far, offset),
        "lightDirection": [float(v) for v in source],
        "lightColor": [float(v) for v in light.colour],
        "lightDistance": float(light.distance),
        "shadow": int(light.shadow),
        "lightAmbientCoeff": float(light.ambient),
        "lightDiffuseCoeff": float(light.diffuse),
        "lightSpecularCoeff": float(light.specular),
        "renderer": pybullet.ER_TINY_RENDERER,
    }


def window_around(centre: tuple[float, float], half_size: int, model: CameraModel) -> Window:
    """A window of ``2 half_size + 1`` pixels square centred on pixel ``centre`` ``(u, v)``
    (rounded to the nearest pixel), cut to the sensor; raises ValueError if nothing is left."""
    width, height = model.resolution
    cu, cv = round(float(centre[0])), round(float(centre[1]))
    window = (
        max(cu - half_size, 0),
        min(cu + half_size + 1, width),
        max(cv - half_size, 0),
        min(cv + half_size + 1, height),
    )
    return check_window(window, model)
