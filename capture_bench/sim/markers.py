"""The target as the rendered camera sees it: four coloured sphere markers and a small grey block.

The markers are what `capture_bench.sensing.detector` looks for, so their colours are chosen
against everything else in the world (``assets/arm.urdf`` and `capture_bench.sim.world`):

========================  ===================  ======  ==========
surface                   RGB                  hue     saturation
========================  ===================  ======  ==========
arm white, column, hubs   greys                any     <= 0.08
arm blue                  (0.25, 0.45, 0.75)   216 deg 0.67
tip orange                (0.95, 0.55, 0.10)   32 deg  0.89
target block, floor       greys                any     <= 0.08
marker 0 red              (0.90, 0.05, 0.05)   0 deg   0.94
marker 1 green            (0.05, 0.80, 0.05)   120 deg 0.94
marker 2 cyan             (0.05, 0.80, 0.80)   180 deg 0.94
marker 3 magenta          (0.80, 0.05, 0.80)   300 deg 0.94
========================  ===================  ======  ==========

Every marker hue is at least 32 deg from every other saturated surface and 60 deg from the other
markers. Lighting scales a surface's RGB (ambient and diffuse terms), which keeps its hue and
saturation; only a specular highlight (white) changes them, so the rendered camera renders without
one (`capture_bench.sensing.render_camera.Lighting`).

The target body has no collision shape and an empty collision group and mask, as the world's own
target: it never collides; capture is a geometric test done elsewhere.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from capture_bench._quiet import quiet_c_output

with quiet_c_output():  # pybullet prints its build time on import
    import pybullet
    from pybullet_utils.bullet_client import BulletClient

MARKER_RADIUS = 0.01  # m, radius of each sphere marker
MARKER_NAMES = ("red", "green", "cyan", "magenta")
MARKER_COLOURS: tuple[tuple[float, float, float, float], ...] = (
    (0.90, 0.05, 0.05, 1.0),
    (0.05, 0.80, 0.05, 1.0),
    (0.05, 0.80, 0.80, 1.0),
    (0.80, 0.05, 0.80, 1.0),
)
BLOCK_COLOUR = (0.55, 0.55, 0.6, 1.0)  # the world's target grey
BLOCK_CLEARANCE = 0.5  # gap between the block and each marker's surface, in marker radii
MIN_BLOCK_HALF = 0.005  # m, the block's smallest half extent


def block_extent(features: ArrayLike, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The grey block of a marked target: centre and half extents, target frame, m, (3,) each.

    The block is the features' bounding box shrunk by ``(1 + BLOCK_CLEARANCE) * radius`` on each
    side (at least ``MIN_BLOCK_HALF``), so that a marker at a corner of the box stays clear of it.

    Args:
        features: the feature points in the target frame, metres, shape (N, 3).
        radius: marker radius, metres.
    """
    points = np.asarray(features, dtype=float)
    lo, hi = points.min(axis=0), points.max(axis=0)
    half = np.maximum((hi - lo) / 2.0 - (1.0 + BLOCK_CLEARANCE) * radius, MIN_BLOCK_HALF)
    return (lo + hi) / 2.0, half


def block_corners(features: ArrayLike, radius: float) -> np.ndarray:
    """The 8 corners of `block_extent`'s block, target frame, metres, shape (8, 3)."""
    centre, half = block_extent(features, radius)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    return centre + signs * half


def create_marked_target(
    bullet: BulletClient,
    features: ArrayLike,
    radius: float = MARKER_RADIUS,
    colours: Sequence[Sequence[float]] = MARKER_COLOURS,
    block: bool = True,
) -> int:
    """Create a target body whose frame origin is the capture point, with one sphere marker at
    each feature point, and return its pybullet body id.

    Args:
        bullet: the client to create the body in.
        features: the feature points in the target frame, metres, shape (N, 3), N = len(colours).
        radius: marker radius, metres, > 0.
        colours: RGBA in [0, 1] of each marker, in the order of the features.
        block: add the grey block of `block_extent` (the target's body); without it the
            target is its markers only.

    Returns:
        The body id. Place it with ``resetBasePositionAndOrientation`` (as
        `capture_bench.sim.world.World.set_target_pose` does).
    """
    points = np.asarray(features, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
        raise ValueError(f"features must be a finite (N, 3) array, got shape {points.shape}")
    if len(colours) != len(points):
        raise ValueError(
            f"need one colour per feature: {len(colours)} colours, {len(points)} points"
        )
    if not (radius > 0.0 and np.isfinite(radius)):
        raise ValueError(f"marker radius must be a positive number of metres, got {radius!r}")
    shapes = [pybullet.GEOM_SPHERE] * len(points)
    radii = [float(radius)] * len(points)
    half_extents = [[0.0, 0.0, 0.0]] * len(points)
    positions = points.tolist()
    rgba = [tuple(float(c) for c in colour) for colour in colours]
    if block:
        centre, half = block_extent(points, radius)
        shapes.append(pybullet.GEOM_BOX)
        radii.append(0.0)
        half_extents.append(half.tolist())
        positions.append(centre.tolist())
        rgba.append(BLOCK_COLOUR)
    visual = bullet.createVisualShapeArray(
        shapeTypes=shapes, radii=radii, halfExtents=half_extents, visualFramePositions=positions
    )
    target = bullet.createMultiBody(0.0, -1, visual, basePosition=(0.0, 0.0, 0.0))
    bullet.setCollisionFilterGroupMask(target, -1, 0, 0)
    for index, colour in enumerate(rgba):
        bullet.changeVisualShape(target, -1, shapeIndex=index, rgbaColor=colour)
    return target
