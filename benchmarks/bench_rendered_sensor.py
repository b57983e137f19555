"""Speed and accuracy of the rendered camera sensor (`capture_bench.sensing.rendered_sensor`).

Usage::

    taskset -c 0 python benchmarks/bench_rendered_sensor.py [--poses 200] [--timing-poses 40]
        [--repeats 3] [--clock cpu|wall] [--seed 0] [--skip-accuracy]

Prints, on one core (the process pins itself to the first CPU it may use):

* **speed**: captures per second of `RenderedCamera.capture` with the default settings, the
  windowed path and the full frame, the target 0.9-1.4 m from the lens anywhere in the central
  80 % of the image in a random orientation, the arm at home in view (best of ``--repeats`` passes
  over ``--timing-poses`` poses, a tenth of them for the full frame; CPU time of this process by
  default); then where the windowed capture's time goes, each part timed in the same interleaved
  repeats: rendering its windows (and, of that, what the ``getCameraImage`` calls cost drawing
  a 1 x 1 window each), ``detect_markers`` on them, and the rest (windows, culling, exact-float
  re-detections, bookkeeping);
* **accuracy**: detected minus eq. 2's projection of the marker centres over ``--poses``
  unoccluded poses (target 0.8-2 m from the lens, markers in the central 90 % of the image, no
  marker able to hide another, the arm turned away out of view): per-axis RMS, median and 95th
  percentile of the error's length, pixels, and the share of markers found; for the default
  settings (the value of ``DETECTION_SIGMA_PX``), image noise 0/4/8 grey levels, and 20 ms of
  exposure with the target moving at 0.05 m/s in a random direction (the error is measured
  against the position at the end of the exposure, as the sensor reports it);
* **light**: the same poses at diffuse intensity 1, 0.3 and 0 and lit from the side (+x, -x, +z
  and from behind the target).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.detector import MARKER_BANDS, detect_markers
from capture_bench.sensing.occlusion import hidden_markers
from capture_bench.sensing.pixels import pixel_of, pixel_to_global
from capture_bench.sensing.render_camera import lens_position
from capture_bench.sensing.rendered_sensor import (
    RenderedCamera,
    RenderSettings,
    marker_windows,
)
from capture_bench.sim import kinematics
from capture_bench.sim.markers import MARKER_RADIUS
from capture_bench.sim.target_motion import FEATURE_POINTS, random_rotation, random_unit_vector
from capture_bench.task.scenarios import CameraConfig

FEATURES = FEATURE_POINTS["non_coplanar"]
ARM_AWAY = np.array([np.pi, np.pi / 2, 0.0])  # rad: the arm points to -x, out of the camera's view
SPEED = 0.05  # m/s, the paper's target speed
CLOCKS = {"cpu": time.process_time, "wall": time.perf_counter}
Pose = tuple[np.ndarray, np.ndarray, np.ndarray]  # capture point (3,), R_gt (3, 3), velocity (3,)


def default_camera() -> CameraModel:
    """The scenarios' default camera (CameraConfig)."""
    return CameraConfig().model()


def draw_poses(
    model: CameraModel,
    rng: np.random.Generator,
    count: int,
    depths: tuple[float, float],
    clear: bool,
) -> list[Pose]:
    """Target poses with the capture point at a random pixel of the central 80 % of the image,
    ``depths`` m beyond the lens, every marker in the central 90 % and above the floor; with
    ``clear``, no marker able to hide another (`hidden_markers`)."""
    poses: list[Pose] = []
    width, height = model.resolution
    while len(poses) < count:
        pixel = rng.uniform([0.1 * width, 0.1 * height], [0.9 * width, 0.9 * height])
        position = pixel_to_global(pixel[None], np.array([rng.uniform(*depths)]), model)[0]
        rotation = random_rotation(rng)
        points = position + FEATURES @ rotation.T
        if not model.visible(model.to_camera(points), margin=0.1).all():
            continue
        if points[:, 2].min() < -kinematics.L0 + 2 * MARKER_RADIUS:
            continue
        if clear and hidden_markers(model, points, MARKER_RADIUS).any():
            continue
        poses.append((position, rotation, SPEED * random_unit_vector(rng)))
    return poses


def moving_pose(pose: Pose, moving: bool) -> Callable[[float], tuple[np.ndarray, np.ndarray]]:
    """``pose_at(t)`` of a target at ``pose`` at t = 0, drifting at its velocity if ``moving``."""
    position, rotation, velocity = pose
    v = velocity if moving else np.zeros(3)
    return lambda t: (position + v * t, rotation)


def best_rate(
    call: Callable[[], object], calls: int, repeats: int, timer: Callable[[], float]
) -> float:
    """Best-of-``repeats`` calls per second of ``calls`` calls of ``call()``."""
    best = 0.0
    for _ in range(repeats):
        start = timer()
        for _ in range(calls):
            call()
        best = max(best, calls / max(timer() - start, 1e-12))
    return best


def speed(model: CameraModel, args: argparse.Namespace) -> None:
    """Captures per second, windowed and full frame, and the windowed capture's breakdown."""
    rng = np.random.default_rng(args.seed)
    timer = CLOCKS[args.clock]
    poses = draw_poses(model, rng, args.timing_poses, (0.9, 1.4), clear=False)
    pose_ats = [moving_pose(pose, False) for pose in poses]

    def theta_at(t: float) -> np.ndarray:
        return kinematics.HOME

    print(f"speed: one core, {args.clock} time, best of {args.repeats}")
    with RenderedCamera(model, FEATURES, RenderSettings(windowed=False)) as full:
        full_episode = full.reset(np.random.default_rng(0))
        some = pose_ats[: max(3, len(poses) // 10)]

        def full_frames() -> None:
            for k, pose_at in enumerate(some):
                full.capture(full_episode, pose_at, 0.0, theta_at, rng, k)

        full_ms = 1e3 / best_rate(full_frames, 1, args.repeats, timer) / len(some)
    with RenderedCamera(model, FEATURES) as camera:
        episode = camera.reset(np.random.default_rng(0))
        jobs = []  # per capture: pose_at, its windows, their markers and images
        for pose, pose_at in zip(poses, pose_ats):
            centres = model.to_camera(pose[0] + FEATURES @ pose[1].T)[None]
            looked = list(enumerate(marker_windows(model, centres, MARKER_RADIUS)))
            markers = [i for i, w in looked if w is not None]
            windows = [w for _, w in looked if w is not None]
            jobs.append(
                (pose_at, windows, markers, camera.images(pose_at, 0.0, theta_at, 0, windows))
            )

        def captures() -> None:
            for k, pose_at in enumerate(pose_ats):
                camera.capture(episode, pose_at, 0.0, theta_at, rng, k)

        def render() -> None:
            for pose_at, windows, _, _ in jobs:
                camera.images(pose_at, 0.0, theta_at, 0, windows)

        def detect() -> None:
            for _, windows, markers, images in jobs:
                for window, i, image in zip(windows, markers, images):
                    detect_markers(image, model, (window[0], window[2]), [MARKER_BANDS[i]])

        def calls() -> None:
            for pose_at, windows, _, _ in jobs:
                camera.images(pose_at, 0.0, theta_at, 0, [(10, 11, 10, 11)] * len(windows))

        parts = {"capture": captures, "render": render, "detect": detect, "call": calls}
        best = dict.fromkeys(parts, float("inf"))
        for _ in range(args.repeats):  # interleaved, so that the machine's load hits all alike
            for name, run in parts.items():
                start = timer()
                run()
                best[name] = min(best[name], timer() - start)
    ms = {name: 1e3 * value / len(poses) for name, value in best.items()}
    per_capture = sum(len(windows) for _, windows, _, _ in jobs) / len(poses)
    print(f"  windowed    {1e3 / ms['capture']:7.1f} captures/s ({ms['capture']:.2f} ms)")
    print(f"  full frame  {1e3 / full_ms:7.1f} captures/s ({full_ms:.2f} ms)")
    rest = ms["capture"] - ms["render"] - ms["detect"]
    print(f"  where a windowed capture's time goes ({per_capture:.2f} windows):")
    print(
        f"    render    {ms['render']:5.2f} ms, of which {ms['call']:.2f} ms the calls themselves"
    )
    print("              (a 1 x 1 window each: drawing nothing costs this much)")
    print(f"    detect    {ms['detect']:5.2f} ms (detect_markers on the windows)")
    print(
        f"    the rest  {rest:5.2f} ms (windows, culling, exact-float re-detections, bookkeeping)"
    )


def errors(
    model: CameraModel, poses: Sequence[Pose], settings: RenderSettings
) -> tuple[np.ndarray, float]:
    """Detected minus eq. 2 at the end of the exposure (pixels, (M, 2)) of the markers found, and
    the share found."""
    found_errors, found = [], 0
    with RenderedCamera(model, FEATURES, settings) as camera:
        episode = camera.reset(np.random.default_rng(1))
        for k, pose in enumerate(poses):
            position, rotation, _ = pose
            pose_at = moving_pose(pose, settings.exposure_s > 0.0)
            result = camera.detect(pose_at, 0.0, lambda t: ARM_AWAY, k, episode)
            truth = pixel_of(model.to_camera(position + FEATURES @ rotation.T), model)
            found += int(result.found.sum())
            found_errors.append((result.pixels - truth)[result.found])
    return np.concatenate(found_errors), found / (len(FEATURES) * len(poses))


def summary(e: np.ndarray, share: float) -> str:
    """Per-axis RMS, median and p95 of the error's length (px), and the share found."""
    norm = np.linalg.norm(e, axis=1)
    return (
        f"rms/axis {np.sqrt(np.mean(e**2)):.3f}  median {np.median(norm):.3f}  "
        f"p95 {np.percentile(norm, 95):.3f} px  found {share:.3f}"
    )


def accuracy(model: CameraModel, args: argparse.Namespace) -> None:
    """Detection error tables (module docstring)."""
    poses = draw_poses(model, np.random.default_rng(args.seed + 1), args.poses, (0.8, 2.0), True)
    print(f"accuracy: detected - eq. 2, {args.poses} unoccluded poses 0.8-2 m, arm out of view")
    base = RenderSettings()
    rows = [("default", base)]
    rows += [(f"noise {s:g} grey levels", replace(base, image_noise=s)) for s in (4.0, 8.0)]
    rows += [("exposure 20 ms, 0.05 m/s", replace(base, exposure_s=0.02))]
    rows += [("exposure 20 ms, noise 8", replace(base, exposure_s=0.02, image_noise=8.0))]
    for name, settings in rows:
        print(f"  {name:28s} {summary(*errors(model, poses, settings))}")
    print("light: the same poses")
    side = lens_position(model) - model.position  # the lens, seen from the image-plane centre
    lights = [
        ("intensity 1 (from the lens)", base),
        ("intensity 0.3", replace(base, light_intensity=0.3)),
        ("intensity 0 (ambient only)", replace(base, light_intensity=0.0)),
        ("from +x", replace(base, light_direction=(1.0, 0.0, 0.0))),
        ("from -x", replace(base, light_direction=(-1.0, 0.0, 0.0))),
        ("from +z", replace(base, light_direction=(0.0, 0.0, 1.0))),
        ("from behind the target", replace(base, light_direction=tuple(-side))),
    ]
    for name, settings in lights:
        print(f"  {name:28s} {summary(*errors(model, poses, settings))}")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Speed and accuracy of the rendered camera.")
    parser.add_argument("--poses", type=int, default=200, help="unoccluded poses for accuracy")
    parser.add_argument("--timing-poses", type=int, default=40, help="poses cycled for speed")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats (best is kept)")
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--skip-accuracy", action="store_true", help="print the speed only")
    args = parser.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    model = default_camera()
    speed(model, args)
    if not args.skip_accuracy:
        accuracy(model, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
