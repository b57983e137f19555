"""Environment steps per second, per scenario and observation source, and against panda-gym.

Runs one process with a fixed random action sequence and reports steps/s including resets and
the end-of-episode physical-limit bound, plus microseconds per step. Pin it to one core with
``taskset -c 0`` (numpy's BLAS is held to one thread here). ``--num-envs N`` measures the batched
vector env instead (``gymnasium.make_vec(id, num_envs=N)``): env steps/s counts every sub-env's
step, and includes the recording of the episodes ahead (camera, EKF, bound) and the autoresets.

``--panda`` times panda-gym's ``PandaReach-v3`` single env the same way (the same actions, a
reset on termination or truncation, its 50-step ``TimeLimit`` kept, the env checker left out as
it is for ``CaptureEnv``) right after each capture-bench row, and prints the ratio of the two:
pairing them keeps the ratio meaningful when the machine's speed drifts. ``--repeats R`` runs
the whole sweep R times and ends with each row's median and its range (min-max), the ratio's
taken pair by pair. Usage::

    python benchmarks/bench_env.py      # every scenario x {ekf, photogrammetry, truth}
    python benchmarks/bench_env.py --scenarios paper --sources ekf --seconds 10
    taskset -c 0 python benchmarks/bench_env.py --sources ekf --panda --repeats 5
    python benchmarks/bench_env.py --scenarios jitter --sources ekf --steps 2000   # fixed work
    taskset -c 0 python benchmarks/bench_env.py --sources ekf --num-envs 64 --seconds 20
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import time

# One core means one BLAS thread too (numpy's OpenBLAS would otherwise start one per core and
# fight the measured process for it).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import gymnasium as gym  # noqa: E402 (after the thread settings)
import numpy as np  # noqa: E402

import capture_bench  # noqa: E402
from capture_bench._quiet import quiet_c_output  # noqa: E402
from capture_bench.sensing.sources import SOURCES  # noqa: E402
from capture_bench.task.scenarios import list_scenarios, load_scenario  # noqa: E402

PANDA_ID = "PandaReach-v3"


def capture_env(env_id: str, source: str) -> gym.Env:
    """capture-bench's single env, unwrapped: it truncates itself at its time limit."""
    return gym.make(env_id, observation_source=source).unwrapped


def panda_env() -> gym.Env:
    """panda-gym's ``PandaReach-v3`` with only the ``TimeLimit`` that truncates its episodes
    (50 steps)."""
    import panda_gym  # noqa: F401  (registers PandaReach-v3)

    with quiet_c_output():  # pybullet's "argv[0]=" lines, from C
        env = gym.make(PANDA_ID).unwrapped
    return gym.wrappers.TimeLimit(env, gym.spec(PANDA_ID).max_episode_steps)


def steps_per_second(
    env: gym.Env, seconds: float, seed: int = 0, steps: int | None = None
) -> tuple[float, int]:
    """(steps per second, episodes) for a random-action agent on ``env``, resets included, over
    ``seconds`` of wall time or, given ``steps``, exactly that many steps; closes ``env``."""
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, (4096, 3)).astype(np.float32)
    env.reset(seed=seed)
    taken = episodes = 0

    def unfinished() -> bool:
        if steps is None:
            return time.perf_counter() - start < seconds
        return taken < steps

    start = time.perf_counter()
    while unfinished():
        for _ in range(256 if steps is None else min(256, steps - taken)):
            _, _, terminated, truncated, _ = env.step(actions[taken % 4096])
            taken += 1
            if terminated or truncated:
                episodes += 1
                env.reset()
    rate = taken / (time.perf_counter() - start)
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


def spread(values: list[float], digits: int = 0) -> str:
    """``median (min-max)`` of ``values``, rounded to ``digits``."""
    return (
        f"{statistics.median(values):.{digits}f} "
        f"({min(values):.{digits}f}-{max(values):.{digits}f})"
    )


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
    parser.add_argument(
        "--panda",
        action="store_true",
        help=f"time panda-gym's {PANDA_ID} after each single-env row and print the ratio",
    )
    parser.add_argument(
        "--repeats", type=int, default=1, help="sweeps; with more than 1, a summary of medians"
    )
    parser.add_argument(
        "--steps",
        type=int,
        default=None,
        help="single env: exactly N steps a row instead of --seconds (fixed work, to compare "
        "two versions by instruction count or CPU time)",
    )
    args = parser.parse_args(argv)
    if args.panda and args.num_envs:
        parser.error("--panda compares the single env; leave out --num-envs")
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    if args.steps is not None and (args.steps < 1 or args.num_envs):
        parser.error("--steps takes N >= 1 and times the single env (no --num-envs)")
    if args.panda and importlib.util.find_spec("panda_gym") is None:
        parser.error("--panda needs panda-gym: pip install panda-gym")
    kind = f"vector env of {args.num_envs}" if args.num_envs else "single env"
    print(f"capture-bench {capture_bench.__version__}: env steps/s, random actions, {kind}")
    header = f"{'scenario':10s} {'source':15s} {'steps/s':>9s} {'us/step':>8s} {'episodes':>8s}"
    print(header + (f" {PANDA_ID + ' steps/s':>22s} {'ratio':>6s}" if args.panda else ""))
    rows = [(name, source) for name in args.scenarios for source in args.sources]
    rates: dict[tuple[str, str], list[float]] = {row: [] for row in rows}
    ratios: dict[tuple[str, str], list[float]] = {row: [] for row in rows}
    pandas: list[float] = []
    for _ in range(args.repeats):
        for name, source in rows:
            env_id = load_scenario(name).env_id
            if args.num_envs:
                rate, episodes = vector_steps_per_second(
                    env_id, source, args.seconds, args.num_envs
                )
            else:
                env = capture_env(env_id, source)
                rate, episodes = steps_per_second(env, args.seconds, steps=args.steps)
            rates[name, source].append(rate)
            line = f"{name:10s} {source:15s} {rate:9.0f} {1e6 / rate:8.1f} {episodes:8d}"
            if args.panda:
                panda, _ = steps_per_second(panda_env(), args.seconds, steps=args.steps)
                pandas.append(panda)
                ratios[name, source].append(rate / panda)
                line += f" {panda:22.0f} {rate / panda:6.2f}"
            print(line, flush=True)
    if args.repeats > 1:
        per_row = f"{args.seconds:g} s" if args.steps is None else f"{args.steps} steps"
        print(f"\nmedian (min-max) of {args.repeats} sweeps, {per_row} a row")
        head = f"{'scenario':10s} {'source':15s} {'steps/s':>20s}"
        print(head + ("  ratio" if args.panda else ""))
        for row in rows:
            line = f"{row[0]:10s} {row[1]:15s} {spread(rates[row]):>20s}"
            if args.panda:
                line += f"  {spread(ratios[row], 2)}"
            print(line)
        if args.panda:
            print(f"{PANDA_ID}: {spread(pandas)} steps/s over every row")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
