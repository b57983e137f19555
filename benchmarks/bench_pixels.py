"""Env steps per second of the batched env with the pixel observation, and where the time goes.

For each N, runs ``CaptureVectorEnv(N, scenario, observation_source="pixels")`` with random
actions (autoresets, the recording of episodes ahead and the EKF for ``info`` included) and
counts every sub-env's step; then the same env with the scenario's estimator observation, whose
steps/s is the cost of everything but the images; and the renderer alone
(``WorkspaceImager.render_batch`` over N random arm and target poses), in microseconds per
image. With ``--option KEY=VALUE`` (the pixel observation's options: ``frame_stack``,
``ee_crop``, ``ee_crop_scale``, ``image_supersample``, ``ee_crop_supersample``) a last column
times the batched env with those options too. Pin it to one core with ``taskset -c 0`` (numpy's
BLAS is held to one thread here). Usage::

    taskset -c 0 python benchmarks/bench_pixels.py                      # N = 16 and 64, 84 x 84
    taskset -c 0 python benchmarks/bench_pixels.py --num-envs 64 --seconds 20 --size 64 64
    taskset -c 0 python benchmarks/bench_pixels.py --option frame_stack=3 --option ee_crop=49
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Sequence

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402 (after the thread settings)

from capture_bench.engine.task import CaptureTask  # noqa: E402
from capture_bench.envs.vector_env import CaptureVectorEnv  # noqa: E402


def env_steps_per_second(env: CaptureVectorEnv, seconds: float, seed: int = 0) -> float:
    """Sub-env steps per second of ``env`` under uniform random actions, over ``seconds`` of
    wall time after the first reset; closes ``env``."""
    rng = np.random.default_rng(seed)
    n = env.num_envs
    actions = rng.uniform(-1.0, 1.0, (64, n, 3)).astype(np.float32)
    env.reset(seed=seed)
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(16):
            env.step(actions[steps % 64])
            steps += 1
    elapsed = time.perf_counter() - start
    env.close()
    return steps * n / elapsed


def render_us_per_image(scenario: str, size: tuple[int, int], n: int, repeats: int = 20) -> float:
    """Microseconds per image of ``render_batch`` over n random poses (arm joints in their
    limits, the target near the middle of the workspace, random attitudes)."""
    task = CaptureTask(scenario, observation_source="pixels", image_size=size)
    imager = task.imager()
    rng = np.random.default_rng(0)
    arm = task.description.arm
    theta = rng.uniform(arm.joint_lower, arm.joint_upper, (n, 3))
    position = np.array([0.55, 0.0, 0.4]) + rng.uniform(-0.2, 0.2, (n, 3))
    q, _ = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    imager.render_batch(theta, position, q)  # warm up
    start = time.perf_counter()
    for _ in range(repeats):
        imager.render_batch(theta, position, q)
    elapsed = time.perf_counter() - start
    imager.close()
    return elapsed / (repeats * n) * 1e6


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--num-envs", type=int, nargs="+", default=[16, 64])
    parser.add_argument("--size", type=int, nargs=2, default=[84, 84], metavar=("W", "H"))
    parser.add_argument("--seconds", type=float, default=10.0, help="wall time per measurement")
    parser.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a pixel observation option for the last column (repeat for several)",
    )
    args = parser.parse_args(argv)
    size = (args.size[0], args.size[1])
    options = _options(parser, args.option)
    print(f"scenario {args.scenario}, image {size[0]} x {size[1]}, pid {os.getpid()}")
    if options:
        print("options: " + ", ".join(f"{k}={v}" for k, v in options.items()))
    header = f"{'N':>4} {'pixels steps/s':>15} {'estimate steps/s':>17} {'render us/image':>16}"
    print(header + (f" {'options steps/s':>16}" if options else ""))
    for n in args.num_envs:
        pixels = CaptureVectorEnv(n, args.scenario, observation_source="pixels", image_size=size)
        with_pixels = env_steps_per_second(pixels, args.seconds)
        without = env_steps_per_second(CaptureVectorEnv(n, args.scenario), args.seconds)
        render = render_us_per_image(args.scenario, size, n)
        row = f"{n:>4} {with_pixels:>15.0f} {without:>17.0f} {render:>16.0f}"
        if options:
            env = CaptureVectorEnv(
                n, args.scenario, observation_source="pixels", image_size=size, **options
            )
            row += f" {env_steps_per_second(env, args.seconds):>16.0f}"
        print(row)


def _options(parser: argparse.ArgumentParser, pairs: Sequence[str]) -> dict[str, int]:
    """``KEY=VALUE`` pairs as the env's keyword arguments (checked by the env)."""
    from capture_bench.sensing.workspace_image import PixelOptions

    options = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        if not value.isdigit():
            parser.error(f"--option {pair!r}: expected KEY=VALUE with a whole number")
        options[key] = int(value)
    try:
        return PixelOptions.check(**options).changed()
    except ValueError as exc:
        parser.error(f"--option: {exc}")


if __name__ == "__main__":
    main()
