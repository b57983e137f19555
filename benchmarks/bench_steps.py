"""A fixed amount of env stepping, for comparing two versions of the package by CPU time.

Plays ``--steps`` steps of ``CaptureEnv`` (``--num-envs 1``) or of ``CaptureVectorEnv`` (more),
seeded episodes and small random actions drawn from one seed, resets and autoresets included, and
prints the CPU time per env step. The work is the same whatever the machine's load, so the whole
process's CPU seconds compare two versions of the package (the startup, ~1-2 s of imports,
included)::

    taskset -c 0 python benchmarks/bench_steps.py --num-envs 1 --steps 20000
    python benchmarks/compare_commits.py BASE HEAD --bench \\
        "single=python $PWD/benchmarks/bench_steps.py --num-envs 1 --steps 20000" \\
        "vector=python $PWD/benchmarks/bench_steps.py --num-envs 64 --steps 600"

Only the public API is used, so the same script (by its absolute path) times any version.
"""

from __future__ import annotations

import argparse
import os
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from capture_bench.envs.capture_env import CaptureEnv  # noqa: E402
from capture_bench.envs.vector_env import CaptureVectorEnv  # noqa: E402


def single(scenario: str, steps: int) -> float:
    """CPU seconds of ``steps`` single-env steps (a new seeded episode after each end)."""
    env = CaptureEnv(scenario)
    actions = np.random.default_rng(0).uniform(-0.05, 0.05, (steps, 3))
    seed = 0
    env.reset(seed=seed)
    start = time.process_time()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            seed += 1
            env.reset(seed=seed)
    spent = time.process_time() - start
    env.close()
    return spent


def vector(scenario: str, num_envs: int, steps: int) -> float:
    """CPU seconds of ``steps`` vector-env steps of ``num_envs`` sub-envs (next-step autoreset)."""
    env = CaptureVectorEnv(num_envs, scenario)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, num_envs, 3)).astype(np.float32)
    env.reset(seed=0)
    start = time.process_time()
    for action in actions:
        env.step(action)
    spent = time.process_time() - start
    env.close()
    return spent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenarios", nargs="+", default=["paper", "noisy"])
    parser.add_argument("--num-envs", type=int, default=1, help="1: CaptureEnv; more: vector")
    parser.add_argument("--steps", type=int, default=20000, help="env steps (vector: per sub-env)")
    args = parser.parse_args()
    if args.num_envs < 1 or args.steps < 1:
        parser.error("--num-envs and --steps take whole numbers >= 1")
    print("scenario  envs  steps  cpu us per env step")
    for name in args.scenarios:
        if args.num_envs == 1:
            spent, count = single(name, args.steps), args.steps
        else:
            spent, count = vector(name, args.num_envs, args.steps), args.steps * args.num_envs
        print(f"{name:9s} {args.num_envs:4d} {count:6d}  {spent / count * 1e6:.1f}")


if __name__ == "__main__":
    main()
