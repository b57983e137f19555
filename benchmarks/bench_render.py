"""Cost and accuracy of the rendered camera: TinyRenderer frames and windows, and the detector.

Usage::

    python benchmarks/bench_render.py [--poses 50] [--repeats 5] [--seed 0]

Prints, on one core (the process is pinned to the first CPU it may use):

* milliseconds per full frame at 1280 x 960 and 640 x 480 (the same field of view), and per
  64 x 64 window, with the arm at home and the target in view (best of ``--repeats``);
* milliseconds per detection of the four markers in a full frame and in a 64 x 64 window;
* the detector's error against eq. 2 (and against the exact ellipse centre of
  `capture_bench.sensing.pixels.sphere_image`) over ``--poses`` random target poses at the
  default camera placement (0.25-0.35 m from the home end-effector, markers in the central 90 % of
  the image, uniformly random orientation) that are unoccluded by geometry: no marker image can
  overlap a nearer marker's or the block's (`capture_bench.sensing.occlusion.hidden_markers`)
  and the target lies in front of the arm (global y < -0.06 m);
* over every in-view pose drawn, occluded or not: the share of frames with all four markers found
  and each marker status's count, and the error of the markers found on frames that geometry says
  may be occluded (what a partial occlusion that passes the fill test costs);
* the error of a single marker by distance from the lens (windows, random positions on the
  sensor and random mesh orientations).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable, Sequence

import numpy as np

from capture_bench._quiet import quiet_c_output
from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.detector import STATUS_NAMES, detect_markers
from capture_bench.sensing.occlusion import hidden_markers
from capture_bench.sensing.pixels import pixel_of, pixel_to_global, sphere_image
from capture_bench.sensing.render_camera import render_frame, window_around
from capture_bench.sim import kinematics
from capture_bench.sim.markers import (
    MARKER_COLOURS,
    MARKER_RADIUS,
    block_corners,
    create_marked_target,
)
from capture_bench.sim.rotations import quaternion_xyzw
from capture_bench.sim.target_motion import FEATURE_POINTS, random_rotation, random_unit_vector
from capture_bench.sim.world import World
from capture_bench.task.scenarios import CameraConfig

with quiet_c_output():
    import pybullet
    from pybullet_utils.bullet_client import BulletClient

FEATURES = FEATURE_POINTS["non_coplanar"]
ARM_CLEARANCE_Y = -0.06  # m: every arm surface has global y >= -0.05 with theta1 = 0
DISTANCES = (0.8, 1.2, 2.0, 3.0, 4.0)  # m from the lens, for the single-marker table


def default_camera(resolution: tuple[int, int] = (1280, 960)) -> CameraModel:
    """The scenarios' default camera; another resolution keeps the field of view (pitch scaled)."""
    cfg = CameraConfig()
    return CameraModel.looking_at(
        cfg.position,
        cfg.look_at,
        focal_length=cfg.focal_length,
        pixel_pitch=cfg.pixel_pitch * cfg.resolution[0] / resolution[0],
        resolution=resolution,
    )


def best_ms(call: Callable[[], object], repeats: int, inner: int) -> float:
    """Best-of-``repeats`` mean wall time of ``call()`` over ``inner`` calls, milliseconds."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(inner):
            call()
        best = min(best, (time.perf_counter() - start) / inner * 1e3)
    return best


def draw_pose(model: CameraModel, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """A target pose at the default placement with every marker in the central 90 % of the image:
    ``(position, rotation, marker centres (4, 3), block corners (8, 3))``, global, m."""
    home = kinematics.forward_kinematics(kinematics.HOME)
    while True:
        position = home + rng.uniform(0.25, 0.35) * random_unit_vector(rng)
        rotation = random_rotation(rng)
        points = position + FEATURES @ rotation.T
        if model.visible(model.to_camera(points), margin=0.1).all():
            block = position + block_corners(FEATURES, MARKER_RADIUS) @ rotation.T
            return position, rotation, points, block


def summary(errors: Sequence[float]) -> str:
    """Median, 95th percentile and maximum of the finite errors (px), and how many are NaN."""
    e = np.asarray(errors, dtype=float)
    missed = int(np.isnan(e).sum())
    e = e[~np.isnan(e)]
    if e.size == 0:
        return f"none found ({missed} missed)"
    return (
        f"median {np.median(e):.3f}  p95 {np.percentile(e, 95):.3f}  max {e.max():.3f} px"
        f"  (n={e.size}, missed {missed})"
    )


def timings(world: World, model: CameraModel, rng: np.random.Generator, repeats: int) -> None:
    """Render and detection costs (module docstring)."""
    bullet = world.client
    position, rotation, points, _ = draw_pose(model, rng)
    world.reset(kinematics.HOME, position, rotation)
    small = default_camera((640, 480))
    u0, _, v0, _ = window_around(pixel_of(model.to_camera(points[:1]), model)[0], 32, model)
    window = (u0, u0 + 64, v0, v0 + 64)
    frame, patch = render_frame(bullet, model), render_frame(bullet, model, window)
    rows = [
        ("render full 1280x960", lambda: render_frame(bullet, model), 3),
        ("render full 640x480", lambda: render_frame(bullet, small), 5),
        ("render window 64x64", lambda: render_frame(bullet, model, window), 50),
        ("detect 4 markers, full 1280x960", lambda: detect_markers(frame, model), 10),
        ("detect 4 markers, window 64x64", lambda: detect_markers(patch, model, (u0, v0)), 200),
    ]
    print("ms per call (one core, best of repeats)")
    for name, call, inner in rows:
        print(f"  {name:34s} {best_ms(call, repeats, inner):8.3f}")


def pose_errors(world: World, model: CameraModel, rng: np.random.Generator, poses: int) -> None:
    """Detection error on unoccluded full frames, and what happens on all drawn frames."""
    clear_eq2: list[float] = []
    clear_ellipse: list[float] = []
    leaked: list[float] = []
    statuses = np.zeros(len(STATUS_NAMES), dtype=int)
    all_found = drawn = 0
    while len(clear_eq2) < 4 * poses:
        position, rotation, points, block = draw_pose(model, rng)
        in_front = max(points[:, 1].max() + MARKER_RADIUS, block[:, 1].max()) < ARM_CLEARANCE_Y
        hidden = hidden_markers(model, points, MARKER_RADIUS, [block])
        world.reset(kinematics.HOME, position, rotation)
        found = detect_markers(render_frame(world.client, model), model)
        drawn += 1
        all_found += bool(found.found.all())
        statuses += np.bincount(found.status, minlength=len(STATUS_NAMES))
        centres = model.to_camera(points)
        eq2 = np.linalg.norm(found.pixels - pixel_of(centres, model), axis=1)
        if in_front and not hidden.any():
            ellipse = sphere_image(centres, MARKER_RADIUS, model).centre
            clear_eq2 += eq2.tolist()
            clear_ellipse += np.linalg.norm(found.pixels - ellipse, axis=1).tolist()
        elif hidden.any():
            leaked += eq2[hidden & found.found].tolist()
    print(f"detection error on {poses} unoccluded poses (full frames, default camera)")
    print(f"  vs eq. 2 of the centres     {summary(clear_eq2)}")
    print(f"  vs exact ellipse centres    {summary(clear_ellipse)}")
    print(f"all {drawn} in-view poses drawn (arm at home, occluded or not)")
    print(f"  frames with all 4 found     {all_found / drawn:.2f}")
    counts = ", ".join(f"{n} {c}" for n, c in zip(STATUS_NAMES, statuses) if c)
    print(f"  marker statuses             {counts}")
    print(f"  found, maybe occluded       {summary(leaked)}")


def distance_table(model: CameraModel, rng: np.random.Generator) -> None:
    """Single-marker error against eq. 2 by distance from the lens (windows)."""
    with quiet_c_output():
        client = BulletClient(connection_mode=pybullet.DIRECT)
    try:
        body = create_marked_target(
            client, np.zeros((1, 3)), MARKER_RADIUS, MARKER_COLOURS[:1], block=False
        )
        print("one marker (0.01 m) by distance from the lens, 100 random placements each")
        for depth in DISTANCES:
            errors, radius = [], 0.0
            for _ in range(100):
                pixel = rng.uniform([60.0, 60.0], np.array(model.resolution) - 61.0)
                centre = pixel_to_global(pixel[None], np.array([depth]), model)[0]
                orientation = quaternion_xyzw(random_rotation(rng).tolist())
                client.resetBasePositionAndOrientation(body, centre.tolist(), orientation)
                radius = float(
                    sphere_image(model.to_camera(centre[None]), MARKER_RADIUS, model)[2][0]
                )
                window = window_around(pixel, int(radius) + 8, model)
                found = detect_markers(render_frame(client, model, window), model, window[::2])
                errors.append(float(np.linalg.norm(found.pixels[0] - pixel)))
            print(f"  {depth:3.1f} m, image radius {radius:5.1f} px: {summary(errors)}")
    finally:
        client.disconnect()


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Cost and accuracy of the rendered camera.")
    parser.add_argument("--poses", type=int, default=50, help="unoccluded poses to measure")
    parser.add_argument("--repeats", type=int, default=5, help="timing repeats (best is kept)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    model = default_camera()
    rng = np.random.default_rng(args.seed)
    with World(FEATURES, marker_radius=MARKER_RADIUS) as world:
        timings(world, model, rng, args.repeats)
        pose_errors(world, model, rng, args.poses)
    distance_table(model, rng)


if __name__ == "__main__":
    main()
