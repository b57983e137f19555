"""Environment steps per second, per scenario and observation source (issue: env speed).

Runs one process on one core (set ``taskset -c 0`` to pin it) with a fixed action sequence and
reports steps/s including resets and the end-of-episode physical-limit bound, plus microseconds
per step. ``--num-envs N`` measures the batched vector env instead
(``gymnasium.make_vec(id, num_envs=N)``): env steps/s counts every sub-env's step, and includes
the recording of the episodes ahead (camera, EKF, bound) and the autoresets. Usage::

    python benchmarks/bench_env.py      # every scenario x {ekf, photogrammetry, truth}
    python benchmarks/bench_env.py --scenarios paper --sources ekf --seconds 10
    taskset -c 0 python benchmarks/bench_env.py --sources ekf --num-envs 64 --seconds 20
"""

from __future__ import annotations

import argparse
import os
import time

# One core means one BLAS thread too (numpy's OpenBLAS would otherwise start one per core and
# fight the measured process for it).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import gymnasium as gym  # noqa: E402 (after the thread settings)
import numpy as np  # noqa: E402

import capture_bench  # noqa: E402
from capture_bench.sensing.sources import SOURCES  # noqa: E402
from capture_bench.task.scenarios import list_scenarios, load_scenario  # noqa: E402


def steps_per_second(env_id: str, source: str, seconds: float, seed: int = 0) -> tuple[float, int]:
    """(steps per second, episodes) for a random-action agent over ``seconds`` of wall time."""
    env = gym.make(env_id, observation_source=source).unwrapped
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, (4096, 3)).astype(np.float32)
    env.reset(seed=seed)
    steps = episodes = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(256):
            _, _, terminated, truncated, _ = env.step(actions[steps % 4096])
            steps += 1
            if terminated or truncated:
                episodes += 1
                env.reset()
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate, episodes


def vector_steps_per_second(
    env_id: str, source: str, seconds: float, num_envs: int, seed: int = 0
) -> tuple[float, int]:
    """(env steps per second, episodes) for random actions in the batched vector env; the clock
    starts at the first reset, so the first batch of recordings counts."""
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, (256, num_envs, 3)).astype(np.float32)
    start = time.perf_counter()
    env = gym.make_vec(
        env_id, num_envs, vectorization_mode="vector_entry_point", observation_source=source
    )
    env.reset(seed=seed)
    steps = episodes = 0
    while steps == 0 or time.perf_counter() - start < seconds:
        for _ in range(16):
            _, _, terminated, truncated, _ = env.step(actions[steps % 256])
            steps += 1
            episodes += int(terminated.sum() + truncated.sum())
    rate = steps * num_envs / (time.perf_counter() - start)
    env.close()
    return rate, episodes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--scenarios", nargs="+", default=list_scenarios(), choices=list_scenarios()
    )
    parser.add_argument("--sources", nargs="+", default=list(SOURCES), choices=SOURCES)
    parser.add_argument("--seconds", type=float, default=3.0, help="wall time per row, s")
    parser.add_argument(
        "--num-envs", type=int, default=0, help="measure the batched vector env with N sub-envs"
    )
    args = parser.parse_args(argv)
    kind = f"vector env of {args.num_envs}" if args.num_envs else "single env"
    print(f"capture-bench {capture_bench.__version__}: env steps/s, random actions, {kind}")
    print(f"{'scenario':10s} {'source':15s} {'steps/s':>9s} {'us/step':>8s} {'episodes':>8s}")
    for name in args.scenarios:
        for source in args.sources:
            env_id = load_scenario(name).env_id
            if args.num_envs:
                rate, episodes = vector_steps_per_second(
                    env_id, source, args.seconds, args.num_envs
                )
            else:
                rate, episodes = steps_per_second(env_id, source, args.seconds)
            print(f"{name:10s} {source:15s} {rate:9.0f} {1e6 / rate:8.1f} {episodes:8d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
