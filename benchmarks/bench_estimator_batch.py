"""Microseconds per env per update of TargetEstimator(n), for each n of ``--sizes``.

Usage::

    python benchmarks/bench_estimator_batch.py [--sizes 1 16 64 256] [--steps 200]
        [--repeats 5] [--seed 0] [--clock wall|cpu]

The scene is ``bench_estimator.py``'s: camera ~1.2 m from a target circling at 1.5 cm/s, 1 px noise,
0.05 s period, every frame delivered; each env has its own noise seed. The first update (the cold
photogrammetry that initialises every filter) is not timed: the figures are steady predict+update
steps. At n = 1 the estimator takes its one-row path. Each figure is the best of
``--repeats`` timed runs of ``--steps`` updates (consecutive frames), divided by steps x envs.
``--clock cpu`` times the process's CPU time instead of the wall clock (steadier on a machine
shared with other work; set ``OPENBLAS_NUM_THREADS=1`` for one core).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_estimator import DT, FEATURES, make_frames  # noqa: E402

from capture_bench.sensing.estimator import TargetEstimator  # noqa: E402


def measure(
    sizes: Sequence[int], steps: int, repeats: int, seed: int, clock: Callable[[], float]
) -> list[tuple[str, float]]:
    """Return (operation, microseconds per env per update) rows."""
    n_max, n_frames = max(sizes), 1 + steps * repeats
    cam = None
    images = np.empty((n_frames, n_max, FEATURES.shape[0], 2))
    for i in range(n_max):
        cam, frames, _ = make_frames(n_frames, seed + i)
        images[:, i] = [f.image_points for f in frames]
    assert cam is not None and np.isfinite(images).all()
    rows = []
    for n in sizes:
        name = f"TargetEstimator(n).update, n = {n}, per env"
        if n == 1:
            name += " (the one-row path)"
        estimator = TargetEstimator(n, cam, FEATURES)
        dt = np.full(n, DT)
        z = np.ascontiguousarray(images[:, :n])
        out = estimator.update(z[0], dt)  # cold photogrammetry: not timed
        assert out.valid.all()
        best = float("inf")
        for r in range(repeats):
            t0 = clock()
            for k in range(1 + r * steps, 1 + (r + 1) * steps):
                out = estimator.update(z[k], dt)
            best = min(best, (clock() - t0) / (steps * n) * 1e6)
        assert (out.status == 0).all()  # every env "ok" throughout
        rows.append((name, best))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark and print a table; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 16, 64, 256])
    parser.add_argument("--steps", type=int, default=200, help="updates per timed run")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs; the best is kept")
    parser.add_argument("--seed", type=int, default=0, help="seed of env 0's image noise")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall")
    args = parser.parse_args(argv)
    if min(args.sizes) < 1 or args.steps < 1 or args.repeats < 1:
        parser.error("--sizes, --steps and --repeats must be >= 1")
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    rows = measure(args.sizes, args.steps, args.repeats, args.seed, clock)
    width = max(len(name) for name, _ in rows)
    print(f"{'operation':<{width}}  us/env/update  env-updates/s")
    print(f"{'-' * width}  -------------  -------------")
    for name, us in rows:
        print(f"{name:<{width}}  {us:13.1f}  {1e6 / us:13.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
