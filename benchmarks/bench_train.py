"""Whole-process training speed of ``train.py`` with each default config in ``configs/algos/``,
against Stable-Baselines3 with the same hyper-parameters on panda-gym's ``PandaReachDense-v3``.

    python benchmarks/bench_train.py                            # every configs/algos/*.yaml
    python benchmarks/bench_train.py --algos ppo --repeats 3    # PPO only, three pairs
    python benchmarks/bench_train.py --steps 20000              # one budget for every config

Every run is a fresh subprocess timed from its start to its exit (imports, set-up, the final
checkpoint and save included), so steps/s is what a user waits for:

* capture-bench: ``python train.py --algo X --total-timesteps N --run-dir <tmp>`` (the default
  batched env, the config's callbacks: progress lines, checkpoints and any evaluation that falls
  within N);
* panda-gym: ``python benchmarks/bench_train.py --panda X N``: SB3's ``DummyVecEnv`` of the
  config's ``n_envs`` ``FlattenObservation(gym.make("PandaReachDense-v3"))`` in a
  ``VecMonitor``, and the same SB3 algorithm built from the same config with the same keyword
  arguments (``sb3_kwargs``: n_steps, batch size, epochs, net, learning rate, train_freq,
  gradient steps, ...; not the capture-bench-only ``features_extractor``) and the same torch
  thread setting, learning N steps.

The two alternate (capture-bench, panda-gym, capture-bench, ...) so that a drift in the
machine's speed hits both; each figure is the median over ``--repeats``. "in learn" is the
steps over the ``model.learn`` time alone (from ``train.py``'s ``done:`` line). PPO runs whole
rollouts, so N is rounded up the same way on both sides.
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs" / "algos"
#: Default budget per config: enough PPO rollouts, and off-policy runs well past learning_starts.
DEFAULT_STEPS = {"ppo": 102_400, "a2c": 102_400}
DEFAULT_OFF_POLICY_STEPS = 30_000
DONE = re.compile(r"done: (\d+) steps in ([\d.]+) s")


def run_panda(algo: str, steps: int) -> None:
    """The panda-gym side, in this (sub)process: learn ``steps`` and print a ``done:`` line."""
    start = time.perf_counter()
    import gymnasium as gym
    import panda_gym  # noqa: F401  (registers PandaReachDense-v3)
    import stable_baselines3
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

    from capture_bench.training.common.build import set_torch_threads
    from capture_bench.training.config.hyperparameters import load_hyperparameters, sb3_kwargs

    hp, _ = load_hyperparameters(algo, CONFIGS / f"{algo}.yaml")
    # The relative-log-distance features read capture-bench's observation layout: panda-gym's
    # network reads its observation as it is (the same layers; the features' small cost stays on
    # capture-bench's side of the comparison).
    hp["policy_kwargs"].pop("features_extractor", None)
    set_torch_threads()
    venv = VecMonitor(
        DummyVecEnv(
            [lambda: gym.wrappers.FlattenObservation(gym.make("PandaReachDense-v3"))] * hp["n_envs"]
        )
    )
    model = getattr(stable_baselines3, algo.upper())(
        hp["policy"], venv, seed=0, device="cpu", **sb3_kwargs(hp, algo)
    )
    learn = time.perf_counter()
    model.learn(total_timesteps=steps)
    now = time.perf_counter()
    print(
        f"done: {model.num_timesteps} steps in {now - learn:.1f} s (set-up {learn - start:.1f} s)"
    )
    venv.close()


def _timed(command: list[str]) -> tuple[float, int, float]:
    """Run ``command`` from the repository root: (wall s, steps done, learn s)."""
    start = time.perf_counter()
    out = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - start
    found = DONE.search(out.stdout)
    if out.returncode or found is None:
        sys.exit(
            f"failed ({out.returncode}): {' '.join(command)}\n{out.stdout[-2000:]}"
            f"{out.stderr[-2000:]}"
        )
    return wall, int(found.group(1)), float(found.group(2))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--algos", nargs="*", help="config names (default: every yaml file)")
    parser.add_argument("--steps", type=int, help="budget of every run (default: per config)")
    parser.add_argument("--repeats", type=int, default=1, help="pairs of runs per config")
    parser.add_argument("--panda", nargs=2, metavar=("ALGO", "STEPS"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))  # this checkout's capture_bench, as train.py (run from ROOT)
    if args.panda:
        run_panda(args.panda[0], int(args.panda[1]))
        return 0
    from capture_bench.training.config.hyperparameters import OFF_POLICY, load_hyperparameters

    algos = args.algos or sorted(p.stem for p in CONFIGS.glob("*.yaml"))
    print(f"$ python benchmarks/bench_train.py {' '.join(argv or sys.argv[1:])}".rstrip())
    rows = []
    for algo in algos:
        hp, _ = load_hyperparameters(algo, CONFIGS / f"{algo}.yaml")
        default = DEFAULT_OFF_POLICY_STEPS if algo in OFF_POLICY else DEFAULT_STEPS.get(algo)
        steps = args.steps or default or 100_000
        ours, panda, ours_learn, panda_learn = [], [], [], []
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory(prefix="bench-train-") as tmp:
                wall, done, learn = _timed(
                    [
                        sys.executable,
                        "train.py",
                        "--algo",
                        algo,
                        "--total-timesteps",
                        str(steps),
                        "--run-dir",
                        f"{tmp}/run",
                    ]
                )
            ours.append(done / wall)
            ours_learn.append(done / learn)
            wall, done_p, learn = _timed(
                [sys.executable, "benchmarks/bench_train.py", "--panda", algo, str(steps)]
            )
            panda.append(done_p / wall)
            panda_learn.append(done_p / learn)
            print(
                f"{algo}: capture-bench {ours[-1]:.0f} steps/s, panda-gym {panda[-1]:.0f} "
                f"({done} / {done_p} steps)",
                flush=True,
            )
        a, b = statistics.median(ours), statistics.median(panda)
        rows.append(
            (
                algo,
                hp["n_envs"],
                done,
                a,
                statistics.median(ours_learn),
                b,
                statistics.median(panda_learn),
                a / b,
            )
        )
    print(
        "\n| config | n_envs | steps | capture-bench steps/s (in learn) "
        "| PandaReachDense-v3 steps/s (in learn) | ratio |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for algo, n_envs, steps, a, a_learn, b, b_learn, ratio in rows:
        print(
            f"| {algo} | {n_envs} | {steps:,} | {a:,.0f} ({a_learn:,.0f}) | {b:,.0f} "
            f"({b_learn:,.0f}) | {ratio:.1f}x |"
        )
    print(f"\nmedian of {args.repeats} whole-process run(s) each, alternating; ratio of medians")
    return 0


if __name__ == "__main__":
    sys.exit(main())
