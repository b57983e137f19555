"""Milliseconds per image of cold photogrammetry (24 starts): solve_poses of one image vs many.

Usage::

    python benchmarks/bench_photogrammetry_batch.py [--images 256] [--repeats 3] [--seed 0]

The images are of random poses (target 0.8-1.6 m away, any orientation) with 1 px noise. Each
figure is the best of ``--repeats`` timed runs over all ``--images`` (the least disturbed by
other processes), divided by the number of images; every call clears the memo of cold
solutions first. Set ``OPENBLAS_NUM_THREADS=1`` to time one core.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np

from capture_bench.sensing import photogrammetry
from capture_bench.sensing.photogrammetry import solve_poses
from capture_bench.sim.rotations import euler_to_matrix, matrix_to_euler

FEATURES = np.array([(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.05)], dtype=float)
FOCAL_LENGTH = 0.008
PITCH = 3.75e-6


def make_images(count: int, seed: int) -> np.ndarray:
    """(count, 4, 2) noisy images of random poses, metres."""
    rng = np.random.default_rng(seed)
    images = np.empty((count, len(FEATURES), 2))
    for i in range(count):
        q = rng.normal(size=4)
        w, x, y, z = q / np.linalg.norm(q)
        angles = matrix_to_euler(
            np.array(
                [
                    [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                    [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                    [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
                ]
            )
        )
        t = np.array([rng.uniform(-0.1, 0.1), rng.uniform(0.8, 1.6), rng.uniform(-0.1, 0.1)])
        p_c = FEATURES @ euler_to_matrix(angles).T + t
        image = -FOCAL_LENGTH * p_c[:, [0, 2]] / (p_c[:, 1:2] - FOCAL_LENGTH)
        images[i] = image + rng.normal(scale=PITCH, size=image.shape)
    return images


def best_ms(run: Callable[[], None], count: int, repeats: int) -> float:
    """Best-of-``repeats`` wall time of ``run``, milliseconds per image."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        best = min(best, (time.perf_counter() - t0) / count * 1e3)
    return best


def measure(count: int, repeats: int, seed: int) -> list[tuple[str, float]]:
    """Return (operation, milliseconds per image) rows."""
    images = make_images(count, seed)

    def single() -> None:
        for z in images:
            photogrammetry.clear_solve_cache()  # time the solve, not the memo of its result
            solve_poses(z[None], FEATURES, FOCAL_LENGTH)

    def batched(m: int) -> Callable[[], None]:
        def run() -> None:
            for start in range(0, count, m):
                photogrammetry.clear_solve_cache()
                solve_poses(images[start : start + m], FEATURES, FOCAL_LENGTH)

        return run

    rows = [("solve_poses cold (24 starts), one image a call", best_ms(single, count, repeats))]
    for m in (16, 64):
        rows.append(
            (f"solve_poses cold, M = {m} images a call", best_ms(batched(m), count, repeats))
        )
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark and print a table; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=256, help="images per timed run")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs; the best is kept")
    parser.add_argument("--seed", type=int, default=0, help="seed of the poses and the noise")
    args = parser.parse_args(argv)
    if args.images < 1 or args.repeats < 1:
        parser.error("--images and --repeats must be >= 1")
    rows = measure(args.images, args.repeats, args.seed)
    width = max(len(name) for name, _ in rows)
    print(f"{'operation':<{width}}  ms/image")
    print(f"{'-' * width}  --------")
    for name, ms in rows:
        print(f"{name:<{width}}  {ms:8.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
