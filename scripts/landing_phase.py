"""Where an agent's capture time goes: the approach to within a distance of the capture point, and
the landing from there to the capture, on a scenario's validation seeds.

Each agent (a built-in name, a model or run directory, ``module:Class``) plays the first N
validation seeds in the single env; per episode, the approach ends at the first step whose
``info["distance"]`` (end-effector to capture point) is below ``--near``, and the landing lasts
from there to the capture time. Prints each agent's medians over the seeds it captured.

    python scripts/landing_phase.py incremental_ik joint_intercept_dls runs/RUN --seeds 40
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.evaluation.running.agents_loading import build_agent, resolve_agent
from capture_bench.evaluation.running.rollout import run_episode
from capture_bench.task.scenarios import load_scenario
from capture_bench.validation import ConfigError


def phases(env: CaptureEnv, agent: object, seed: int, near: float) -> tuple[float, float]:
    """(end of the approach, capture time), s, of one episode as the evaluation plays it
    (`run_episode`, with its per-step trace); NaN where it never comes within ``near`` or is not
    captured."""
    record, trace = run_episode(
        env, agent, agent_name="", scenario=env.scenario.name, seed=seed, trace=True
    )
    assert trace is not None
    within = np.flatnonzero(trace.distance < near)
    approach = float(trace.time[within[0]]) if within.size else math.nan
    return approach, float(record.capture_time)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("agents", nargs="+", help="agents: built-in names, model directories")
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--seeds", type=int, default=40, help="the first N validation seeds")
    parser.add_argument("--near", type=float, default=0.03, help="where the landing starts, m")
    args = parser.parse_args(argv)
    try:
        scenario = load_scenario(args.scenario)
        specs = [resolve_agent(name) for name in args.agents]
    except (ConfigError, ValueError) as exc:
        print(f"landing_phase.py: error: {exc}", file=sys.stderr)
        return 2
    if args.seeds < 1 or not args.near > 0:
        print("landing_phase.py: error: --seeds must be >= 1 and --near > 0 m", file=sys.stderr)
        return 2
    seeds = list(scenario.validation_seeds)[: args.seeds]
    env = CaptureEnv(scenario)
    print(f"{args.scenario}, validation seeds {seeds[0]}..{seeds[-1]}, landing within "
          f"{1e3 * args.near:g} mm; medians over the captured episodes, s")  # fmt: skip
    print("agent | captured | approach | landing | capture time")
    for name, spec in zip(args.agents, specs, strict=True):
        rows = []
        for seed in seeds:
            agent = build_agent(spec, env, seed)
            rows.append(phases(env, agent, seed, args.near))
        approach, capture = np.array(rows).T
        ok = np.isfinite(capture) & np.isfinite(approach)
        print(
            f"{name} | {int(np.isfinite(capture).sum())}/{len(seeds)} | "
            f"{np.median(approach[ok]):.3f} | {np.median(capture[ok] - approach[ok]):.3f} | "
            f"{np.median(capture[ok]):.3f}"
        )
    env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
