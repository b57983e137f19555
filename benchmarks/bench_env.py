"""Environment steps per second, per scenario and observation source (issue: env speed).

Runs one process on one core (set ``taskset -c 0`` to pin it) with a fixed action sequence and
reports steps/s including resets and the end-of-episode physical-limit bound, plus microseconds
per step. Usage::

    python benchmarks/bench_env.py      # every scenario x {ekf, photogrammetry, truth}
    python benchmarks/bench_env.py --scenarios paper --sources ekf --seconds 10
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import capture_bench
from capture_bench.scenarios import list_scenarios, load_scenario

SOURCES = ("ekf", "photogrammetry", "truth")


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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--scenarios", nargs="+", default=list_scenarios(), choices=list_scenarios()
    )
    parser.add_argument("--sources", nargs="+", default=list(SOURCES), choices=SOURCES)
    parser.add_argument("--seconds", type=float, default=3.0, help="wall time per row, s")
    args = parser.parse_args(argv)
    print(f"capture-bench {capture_bench.__version__}: env steps/s, random actions, one process")
    print(f"{'scenario':10s} {'source':15s} {'steps/s':>9s} {'us/step':>8s} {'episodes':>8s}")
    for name in args.scenarios:
        for source in args.sources:
            rate, episodes = steps_per_second(load_scenario(name).env_id, source, args.seconds)
            print(f"{name:10s} {source:15s} {rate:9.0f} {1e6 / rate:8.1f} {episodes:8d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
