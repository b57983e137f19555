"""Arms of trained policies (each the runs of one recipe over training seeds) played on the same
validation seeds of a scenario: each policy's capture rate, median ratio to the physical limit
and mean score, each arm's mean over its training seeds with a 95 % interval (Student's t over the
seeds), and each arm's paired difference in capture rate from the first arm (the episode seeds
resampled, 10,000 bootstrap draws).

    python scripts/validation_comparison.py --scenario paper --episodes 48 \\
        --arm pixels runs/pose-dagger-dls-paper-0 runs/pose-dagger-dls-paper-1 \\
        --arm dagger-dls models/dagger-dls-paper/seeds/0 models/dagger-dls-paper/seeds/1 \\
        --out docs/results/pixels_pose/validation.json

A policy is any model directory `evaluate.py` reads (a finished run, a run's ``best/``, a
shipped model or one of its ``seeds/<seed>/``); pixel policies play in pixel envs with their
own options, as train.py validates them (`validate_policy`: deterministic actions, the batched
env in batches of `CARD_BATCH` seeds). Validation seeds only, never a published one.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from capture_bench.agents.policy_file import PolicyLoadError
from capture_bench.files import atomic_write
from capture_bench.task.scenarios import ConfigError, load_scenario
from capture_bench.training.curves.command import mean_interval
from capture_bench.training.train.model_card import validate_policy

DRAWS = 10_000


def interval(values: list[float]) -> list[float]:
    """The mean of ``values`` and its 95 % interval (Student's t over them, `mean_interval`, as
    the learning curves give it; the mean alone for one)."""
    return list(mean_interval(np.asarray(values, dtype=float))[:3])


def paired_difference(ours: np.ndarray, theirs: np.ndarray, seed: int = 0) -> list[float]:
    """The difference of two arms' capture rates over the same episodes (each (policies,
    episodes), 0/1), and its 95 % bootstrap interval over the episode seeds."""
    per_episode = ours.mean(axis=0) - theirs.mean(axis=0)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(per_episode), (DRAWS, len(per_episode)))
    means = per_episode[draws].mean(axis=1)
    low, high = np.percentile(means, [2.5, 97.5])
    return [float(per_episode.mean()), float(low), float(high)]


def compare(scenario: str, episodes: int, arms: list[list[str]]) -> dict[str, object]:
    seeds = [int(s) for s in load_scenario(scenario).validation_seeds[:episodes]]
    found: dict[str, object] = {}
    captured: dict[str, np.ndarray] = {}
    for name, *directories in arms:
        policies = []
        for directory in directories:
            start = time.perf_counter()
            played = validate_policy(Path(directory), scenario, seeds)
            policies.append({
                "policy": directory,
                "capture_rate": played["capture_rate"],
                "median_ratio_to_limit": played["median_ratio_to_limit"],
                "mean_score": played["mean_score"],
                "captured": [e["captured"] for e in played["episodes"]],
                "wall_clock_s": round(time.perf_counter() - start, 1),
            })  # fmt: skip
            print(f"{name} {directory}: capture rate {played['capture_rate']:.3f}", flush=True)
        captured[name] = np.array([p["captured"] for p in policies], dtype=float)
        found[name] = {
            "policies": policies,
            "capture_rate": interval([p["capture_rate"] for p in policies]),
            "mean_score": interval([p["mean_score"] for p in policies]),
        }
    first = arms[0][0]
    for name in list(found)[1:]:
        found[name]["capture_rate_less_" + first] = paired_difference(  # type: ignore[index]
            captured[name], captured[first]
        )
    return {"scenario": scenario, "seeds": seeds, "arms": found}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--episodes", type=int, default=48, help="the first N validation seeds")
    parser.add_argument("--arm", nargs="+", action="append", required=True,
                        metavar=("NAME", "POLICY"), help="a name, then its policies")  # fmt: skip
    parser.add_argument("--out", type=Path, help="write the report here as JSON")
    args = parser.parse_args(argv)
    bad = [arm[0] for arm in args.arm if len(arm) < 2]
    names = [arm[0] for arm in args.arm]
    twice = sorted({n for n in names if names.count(n) > 1})
    if bad or twice or args.episodes < 1:
        what = (
            f"arm {bad[0]!r} names no policy"
            if bad
            else f"arm name {twice[0]!r} is given twice; give each arm its own name"
            if twice
            else "--episodes must be at least 1"
        )
        print(f"validation_comparison: {what}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    try:
        report = compare(args.scenario, args.episodes, args.arm)
    except (ConfigError, PolicyLoadError) as exc:
        print(f"validation_comparison: {exc}", file=sys.stderr)
        return 2
    words = sys.argv[1:] if argv is None else argv
    report["command"] = "python scripts/validation_comparison.py " + shlex.join(words)
    report["wall_clock_s"] = round(time.perf_counter() - start, 1)
    text = json.dumps(report, indent=2)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(args.out, (text + "\n").encode())
    for name, arm in report["arms"].items():  # type: ignore[union-attr]
        mean, low, high = arm["capture_rate"]
        line = f"{name}: capture rate {mean:.3f} [{low:.3f}, {high:.3f}] over its seeds"
        for key, value in arm.items():
            if key.startswith("capture_rate_less_"):
                low_d, high_d = value[1], value[2]
                line += f"; less {key[18:]}: {value[0]:+.3f} [{low_d:+.3f}, {high_d:+.3f}]"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
