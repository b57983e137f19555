"""The measurements behind the ``grasp`` scenario's tolerance and hold.

On the first ``--seeds`` *validation* seeds of ``grasp`` (never a published evaluation seed):

1. the estimator's late position error: per step with a valid estimate at t >= ``--late`` s (the
   paper captured at ~2.3 s), the largest component of ``X_hat_T - X_T`` (the quantity eq. 20's
   box tests), pooled over steps: median, 95th and 99th percentiles, mm;
2. for every (tolerance, hold) of the grid, the scenario with those values: the capture rate and
   the median ratio to the bound of ``incremental_ik`` and ``incremental_ik_uncapped`` on the EKF
   estimate, and of the privileged ``oracle`` on the truth, with the oracle's largest lag behind
   the bound (capture time - bound) in control periods and how many of its captures lag by more
   than one period.

No agent is changed or tuned: the scenario's values are read off these numbers.

Usage::

    python scripts/measure_grasp.py --seeds 40
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.evaluation.running.rollout import run_episode
from capture_bench.task.scenarios import Scenario, load_scenario

AGENT_SOURCES = (("incremental_ik", None), ("incremental_ik_uncapped", None), ("oracle", "truth"))


def estimator_late_error(scenario: Scenario, seeds: list[int], late: float) -> np.ndarray:
    """Largest component of the estimate's position error, m, at every valid step at t >= late."""
    env = CaptureEnv(scenario, reuse_target_side=True)
    errors = []
    try:
        for seed in seeds:
            env.reset(seed=seed)
            episode = env.recorded_episode
            keep = episode.estimate_valid & (episode.time >= late)
            error = np.abs(episode.estimate_position[keep] - episode.position[keep]).max(axis=1)
            errors.append(error)
    finally:
        env.close()
    return np.concatenate(errors)


def agent_figures(scenario: Scenario, agent_name: str, source: str | None, seeds: list[int]):
    """(capture rate, median ratio to the bound, largest capture - bound in control periods, and
    how many captures lag the bound by more than one period)."""
    env = CaptureEnv(scenario, observation_source=source, reuse_target_side=True)
    agent = make_agent(agent_name, env)
    captured, ratios, lags = 0, [], []
    try:
        for seed in seeds:
            record, _ = run_episode(env, agent, agent_name=agent_name, scenario="", seed=seed)
            if record.captured:
                captured += 1
                ratios.append(record.ratio)
                period = scenario.control.period
                lags.append((record.capture_time - record.physical_limit_time) / period)
    finally:
        env.close()
    median = float(np.nanmedian(ratios)) if ratios else math.nan
    late = sum(lag > 1.0 for lag in lags)
    return captured / len(seeds), median, max(lags) if lags else math.nan, late


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40, help="validation seeds (default 40)")
    parser.add_argument("--late", type=float, default=2.0, help="late means t >= this, s")
    parser.add_argument("--tolerances-mm", type=float, nargs="+", default=[1.0, 2.0, 5.0, 10.0])
    parser.add_argument("--holds", type=float, nargs="+", default=[0.0, 0.2, 0.5])
    args = parser.parse_args(argv)
    base = load_scenario("grasp")
    seeds = list(base.validation_seeds)[: args.seeds]
    error = estimator_late_error(base, seeds, args.late) * 1e3
    q50, q95, q99 = np.percentile(error, [50, 95, 99])
    print(
        f"estimator late position error (largest component, t >= {args.late} s, "
        f"{error.size} steps of {len(seeds)} validation seeds): "
        f"median {q50:.2f} mm, p95 {q95:.2f} mm, p99 {q99:.2f} mm, max {error.max():.2f} mm"
    )
    print("tolerance_mm hold_s " + " ".join(f"{a}:rate,ratio" for a, _ in AGENT_SOURCES), end="")
    print(" oracle_max_lag_periods oracle_later_than_one_period")
    for tolerance in args.tolerances_mm:
        for hold in args.holds:
            scenario = base.replace(capture_tolerance=tolerance * 1e-3, capture={"hold": hold})
            cells, lag, late = [], math.nan, 0
            for agent_name, source in AGENT_SOURCES:
                rate, ratio, lag, late = agent_figures(scenario, agent_name, source, seeds)
                cells.append(f"{rate:.2f},{ratio:.2f}")
            row = f"{tolerance:g} {hold:g} " + " ".join(cells) + f" {lag:.2f} {late}"
            print(row, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
