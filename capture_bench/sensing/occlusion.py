"""Which sphere markers something may hide from the camera, from geometry alone (no rendering).

A marker is *clear* when nothing nearer the lens has an image that comes within ``margin_px`` of
the marker's image (`capture_bench.sensing.pixels.sphere_image`'s ellipse, taken as a disc
of its semi-major axis). Two kinds of occluder are tested:

* the other markers: marker j can hide marker i when j's centre is nearer the lens and the two
  discs overlap;
* convex obstacles given by points on or around them (the corners of the target's block, points
  spread over an arm link): the obstacle's image is the convex hull of its points' pixels, and it
  can hide marker i when that hull comes within the disc and its nearest point is nearer the lens
  than the marker's far side.

The test is conservative: overlapping images say "may be hidden", not "is hidden", so a clear
marker is never partly covered (up to the tessellation of the rendered sphere, which lies inside
the ideal one), while a marker flagged here may still be seen whole.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.pixels import pixel_of, sphere_image

MARGIN_PX = 2.0  # pixels of clearance required around each marker's image


def hidden_markers(
    model: CameraModel,
    centres_global: ArrayLike,
    radius: float,
    obstacles: Sequence[ArrayLike] = (),
    margin_px: float = MARGIN_PX,
) -> NDArray[np.bool_]:
    """Markers that another marker or an obstacle may hide, or that are not wholly beyond the lens.

    Args:
        model: the camera.
        centres_global: marker centres, global, metres, shape (N, 3).
        radius: marker radius, metres.
        obstacles: each a set of points, global, metres, shape (M, 3), whose convex hull contains
            the obstacle (e.g. a box's 8 corners).
        margin_px: clearance required between images, pixels.

    Returns:
        (N,) True where marker i may be (partly) hidden; an obstacle with a point at or behind
        the lens counts as hiding every marker.
    """
    centres_cam = model.to_camera(np.asarray(centres_global, dtype=float).reshape(-1, 3))
    image = sphere_image(centres_cam, radius, model)
    reach = image.semi_major + margin_px
    depth = centres_cam[:, 1]
    hidden = ~np.isfinite(image.semi_major)
    gap = np.linalg.norm(image.centre[:, None, :] - image.centre[None, :, :], axis=-1)
    nearer = depth[None, :] < depth[:, None]  # [i, j]: marker j is nearer the lens than i
    hidden |= np.any(nearer & (gap < reach[:, None] + reach[None, :] - margin_px), axis=1)
    if obstacles:
        hidden |= obstacles_may_hide(model, centres_global, radius, obstacles, margin_px)
    return hidden


def obstacles_may_hide(
    model: CameraModel,
    centres_global: ArrayLike,
    radius: float,
    obstacles: Sequence[ArrayLike],
    margin_px: float = MARGIN_PX,
    behind: bool = False,
) -> NDArray[np.bool_]:
    """Markers that one of the ``obstacles`` may (partly) hide, whatever the markers do to each
    other: `hidden_markers`' obstacle test applied to every marker; with ``behind``, also those
    an obstacle's image comes near from behind (a blurred image mixes a marker's edge with what
    lies behind it).

    Args:
        model: the camera.
        centres_global: marker centres, global, metres, shape (N, 3).
        radius: marker radius, metres.
        obstacles: each a set of points, global, metres, shape (M, 3), whose convex hull contains
            the obstacle (an arm link's bounding box corners).
        margin_px: clearance required between images, pixels.
        behind: count obstacles behind the markers too.

    Returns:
        (N,) True where an obstacle's image comes within ``margin_px`` of marker i's and the
        obstacle reaches nearer the lens than the marker's far side (at any depth with
        ``behind``); every marker when an obstacle point is not beyond the lens.
    """
    centres_cam = model.to_camera(np.asarray(centres_global, dtype=float).reshape(-1, 3))
    image = sphere_image(centres_cam, radius, model)
    reach = image.semi_major + margin_px
    depth = centres_cam[:, 1]
    hidden = np.zeros(len(centres_cam), dtype=bool)
    for points in obstacles:
        cam = model.to_camera(np.asarray(points, dtype=float).reshape(-1, 3))
        if not np.all(model.in_front(cam)):
            return np.ones(len(centres_cam), dtype=bool)
        near = cam[:, 1].min()
        hull = cv2.convexHull(pixel_of(cam, model).astype(np.float32))
        for i in np.flatnonzero(~hidden):
            if (not behind and near >= depth[i] + radius) or not np.isfinite(reach[i]):
                hidden[i] |= not np.isfinite(reach[i])
                continue
            inside = cv2.pointPolygonTest(hull, tuple(map(float, image.centre[i])), True)
            hidden[i] = inside > -reach[i]
    return hidden
