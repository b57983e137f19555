"""Micro-benchmark of the arm's side of one step: ``ArmSide.move``, ``ArmSide.collides``.

Usage::

    python benchmarks/bench_world.py [--steps 20000] [--repeats 3] [--clock cpu|wall]

Prints microseconds per call (best of ``--repeats``; CPU time of this process by default, which
other jobs on a shared machine disturb far less than wall time) for one arm (the single env's
step): ``ArmSide.move`` (rate and joint limits, forward kinematics), ``ArmSide.collides`` (the
screen, and pybullet where it cannot clear the pose), the world's ``collision`` query and
``set_target_pose`` (a rendered env's), and the full arm step (``move`` then ``collides``, as an
env calls them), plus the world's ``reset`` and a 320x240 ``render`` for reference. The arm
wanders near home with random increments at the rate limit's scale (some clipped) and the target
drifts and tumbles, so no call is a degenerate no-op.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence

import numpy as np

from capture_bench.engine.arm import ArmSide
from capture_bench.sim.kinematics import HOME, JOINT_RATE_LIMITS, ArmSpec
from capture_bench.sim.rotations import axis_angle_to_matrix

FEATURES = np.array([(0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (0.0, 0.1, 0.0), (0.0, 0.0, 0.05)])
DT = 0.05  # s, the default control period


CLOCKS = {"cpu": time.process_time, "wall": time.perf_counter}


def measure(
    steps: int = 20000, repeats: int = 3, seed: int = 0, clock: str = "cpu"
) -> dict[str, float]:
    """Microseconds per call of each operation (see the module docstring)."""
    timer = CLOCKS[clock]

    def _best_us(call: Callable[[int], object], steps: int, repeats: int) -> float:
        """Best-of-``repeats`` mean time of ``call(i)`` over ``steps`` calls, microseconds."""
        best = float("inf")
        for _ in range(repeats):
            start = timer()
            for i in range(steps):
                call(i)
            best = min(best, (timer() - start) / steps * 1e6)
        return best

    rng = np.random.default_rng(seed)
    deltas = rng.uniform(-1.2, 1.2, (steps, 1, 3)) * JOINT_RATE_LIMITS * DT
    deltas -= deltas.mean(axis=0)  # no net drift into a joint limit
    dt, ask = np.full(1, DT), np.ones(1, dtype=bool)
    t = np.arange(steps) * DT
    positions = np.c_[0.35 + 0.05 * np.sin(0.1 * t), 0.02 * t % 0.2, np.full(steps, 0.3)]
    rotations = [axis_angle_to_matrix((0.0, 0.6, 0.8), 0.03 * k) for k in t]
    results: dict[str, float] = {}
    arm = ArmSide(FEATURES, ArmSpec())
    world = arm.world
    theta = HOME[None].copy()

    def move(i: int) -> object:
        nonlocal theta
        theta = arm.move(theta, deltas[i], dt)[0]
        return theta

    def full_step(i: int) -> object:
        move(i)
        return arm.collides(theta, ask)

    try:
        world.reset(HOME, positions[0], rotations[0])
        results["ArmSide.move"] = _best_us(move, steps, repeats)
        theta = HOME[None].copy()
        results["ArmSide.collides"] = _best_us(lambda i: arm.collides(theta, ask), steps, repeats)
        results["set_target_pose"] = _best_us(
            lambda i: world.set_target_pose(positions[i], rotations[i]), steps, repeats
        )
        results["collision"] = _best_us(lambda i: world.collision(), steps, repeats)
        theta = HOME[None].copy()
        results["full_step"] = _best_us(full_step, steps, repeats)
        results["reset"] = _best_us(
            lambda i: world.reset(HOME, positions[i], rotations[i]), steps, repeats
        )
        results["render_320x240"] = _best_us(lambda i: world.render(320, 240), 5, 1)
    finally:
        arm.close()
    return results


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000, help="calls per timing")
    parser.add_argument("--repeats", type=int, default=3, help="timings; the best is reported")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random increments")
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="cpu", help="what to time")
    args = parser.parse_args(argv)
    print(f"us per call ({args.clock} time, best of {args.repeats} x {args.steps} calls)")
    for name, us in measure(args.steps, args.repeats, args.seed, args.clock).items():
        print(f"{name:>24s}: {us:10.2f} us/call")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
