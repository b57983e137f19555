"""Microseconds per vision operation: camera capture, the one-row estimator's step per source
(`TargetEstimator(1).update`), its parts, photogrammetry.

Usage::

    python benchmarks/bench_estimator.py [--steps 2000] [--cold 40] [--repeats 3] [--seed 0]

Each figure is the best of ``--repeats`` timed runs (the least disturbed by other processes),
divided by the number of calls. The scene is the default one: camera ~1.2 m from a target circling
at 1.5 cm/s, 1 px noise, 0.05 s period.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np

from capture_bench.sensing import photogrammetry
from capture_bench.sensing.camera import Camera, CameraModel
from capture_bench.sensing.estimator import TargetEstimator
from capture_bench.sensing.photogrammetry import project_poses, projection_table, solve_poses
from capture_bench.sensing.sources import SOURCES
from capture_bench.sim.rotations import euler_to_matrix

FEATURES = np.array([(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.05)], dtype=float)
DT = 0.05


def make_frames(steps: int, seed: int) -> tuple[CameraModel, list, np.ndarray]:
    """Noisy frames of a target circling (5 cm, 0.3 rad/s); returns (camera, frames, positions)."""
    cam = CameraModel.looking_at((0.45, -1.2, 0.45), (0.45, 0.0, 0.4))
    sensor = Camera(cam, noise_px=1.0)
    rng = np.random.default_rng(seed)
    r_gt = euler_to_matrix([0.2, 0.1, -0.3])
    phase = 0.3 * DT * np.arange(steps)
    pos = np.array([0.45, 0.0, 0.4]) + 0.05 * np.column_stack(
        [np.cos(phase), np.zeros(steps), np.sin(phase)]
    )
    state = sensor.reset()
    frames = [sensor.capture(state, p + FEATURES @ r_gt.T, rng) for p in pos]
    return cam, frames, pos


def best_us(run: Callable[[], int], repeats: int) -> float:
    """Best-of-``repeats`` wall time of ``run`` per call it reports making, microseconds."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        calls = run()
        best = min(best, (time.perf_counter() - t0) / calls * 1e6)
    return best


def measure(steps: int, cold: int, repeats: int, seed: int) -> list[tuple[str, float]]:
    """Return (operation, microseconds per call) rows."""
    cam, frames, pos = make_frames(steps, seed)
    images = [f.image_points for f in frames]
    f = cam.focal_length
    (first,) = solve_poses(np.asarray(images[0])[None], FEATURES, f)
    rows = []

    stack = np.array(images)[:, None]  # (steps, 1, N, 2): one row's frames
    no_frame = np.full_like(stack[0], np.nan)
    dt = np.full(1, DT)

    def ekf_predict_only() -> int:
        est = TargetEstimator(1, cam, FEATURES)
        est.update(stack[0], dt)  # initialised by photogrammetry
        for _ in range(steps):
            est.update(no_frame, dt)
        return steps

    def h_and_jacobian() -> int:
        x, table, one = first.pose[None], projection_table(FEATURES, f), np.ones(1, dtype=bool)
        for _ in range(steps):
            project_poses(x, table, 0.0, one)
        return steps

    r_gt = euler_to_matrix([0.2, 0.1, -0.3])
    markers = [p + FEATURES @ r_gt.T for p in pos]

    def camera_captures() -> int:
        sensor = Camera(cam, noise_px=1.0, dropout=0.05)
        state, rng = sensor.reset(), np.random.default_rng(seed)
        for p in markers:
            sensor.capture(state, p, rng)
        return steps

    def estimator_steps(source: str) -> Callable[[], int]:
        def run() -> int:
            est = TargetEstimator(1, cam, FEATURES, source=source)
            zero = np.zeros((1, 3))
            for image, p in zip(stack, pos, strict=True):
                est.update(image, dt, None, (p[None], zero))
            return steps

        return run

    def photogrammetry_warm() -> int:
        guess = first.pose
        for z in images:
            guess = solve_poses(np.asarray(z)[None], FEATURES, f, guess[None])[0].pose
        return steps

    def photogrammetry_cold() -> int:
        for z in images[:cold]:
            photogrammetry.clear_solve_cache()  # time the solve, not the memo of its result
            solve_poses(np.asarray(z)[None], FEATURES, f)
        return cold

    rows.append(
        ("Camera.capture (4 points, noise, 5% drop-out)", best_us(camera_captures, repeats))
    )
    for source in SOURCES:
        rows.append(
            (
                f"TargetEstimator(1).update, source={source}",
                best_us(estimator_steps(source), repeats),
            )
        )
    rows.append(("  ekf without a frame (predict only)", best_us(ekf_predict_only, repeats)))
    rows.append(("  h(X) and H of one pose (project_poses)", best_us(h_and_jacobian, repeats)))
    rows.append(("solve_poses warm (previous solution)", best_us(photogrammetry_warm, repeats)))
    rows.append(("solve_poses cold (24 starts)", best_us(photogrammetry_cold, repeats)))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark and print a table; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="filter steps per timed run")
    parser.add_argument("--cold", type=int, default=40, help="cold photogrammetry solves per run")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs; the best is kept")
    parser.add_argument("--seed", type=int, default=0, help="seed of the image noise")
    args = parser.parse_args(argv)
    if args.steps < 2 or args.cold < 1 or args.repeats < 1:
        parser.error("--steps must be >= 2, --cold and --repeats >= 1")
    rows = measure(args.steps, min(args.cold, args.steps), args.repeats, args.seed)
    width = max(len(name) for name, _ in rows)
    print(f"{'operation':<{width}}  us/call")
    print(f"{'-' * width}  -------")
    for name, us in rows:
        print(f"{name:<{width}}  {us:7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
