"""What the estimate costs an analytic controller: the same agents on the same validation seeds,
fed the EKF's estimate and fed the true target state.

    python scripts/estimate_cost.py                                  # paper, 100 seeds
    python scripts/estimate_cost.py --scenario grasp --seeds 200 --agents incremental_ik dls

Each agent plays the scenario's first ``--seeds`` validation seeds (never a published one) in the
vector env, once with ``observation_source="ekf"`` (the scenario's estimator) and once with
``"truth"``; the table gives the capture rate and the median ratio of capture time to the
episode's physical limit (captures only) of each. The difference is what the estimate costs the
controller; the ratio left under ``truth`` is the controller's own distance from the limit.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import numpy as np

DEFAULT_AGENTS = ("incremental_ik", "dls", "pure_pursuit", "joint_intercept", "planned_intercept")


def measure(
    scenario: str, seeds: Sequence[int], agent_name: str, source: str
) -> tuple[float, float]:
    """(capture rate, median ratio to the physical limit of the captures) of one agent."""
    from gymnasium.vector import AutoresetMode

    from capture_bench.agents import make_agent
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.evaluation.running.rollout import run_episodes

    env = CaptureVectorEnv(
        len(seeds), scenario, observation_source=source, autoreset_mode=AutoresetMode.DISABLED
    )
    try:
        agent = make_agent(agent_name, env.sub_env(0))
        if not getattr(agent, "batched", False):  # one per episode (the oracle reads its own)
            agent = [make_agent(agent_name, env.sub_env(i)) for i in range(len(seeds))]
        records = run_episodes(env, agent, agent_name=agent_name, scenario=scenario, seeds=seeds)
    finally:
        env.close()
    captured = np.array([r.outcome == "captured" for r in records])
    ratios = np.array([r.ratio for r in records], dtype=float)[captured]
    return float(captured.mean()), float(np.median(ratios)) if ratios.size else float("nan")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--seeds", type=int, default=100, help="first N validation seeds")
    parser.add_argument("--agents", nargs="+", default=list(DEFAULT_AGENTS))
    args = parser.parse_args(argv)
    from capture_bench.task.scenarios import load_scenario

    seeds = list(load_scenario(args.scenario).validation_seeds[: args.seeds])
    print(
        f"{args.scenario}, {len(seeds)} validation seeds: capture rate, median ratio to the limit"
    )
    print(f"{'agent':18s} {'ekf':>16s} {'truth':>16s}")
    for name in args.agents:
        cells = [measure(args.scenario, seeds, name, source) for source in ("ekf", "truth")]
        print(f"{name:18s} " + " ".join(f"{rate:6.2f} {ratio:9.3f}" for rate, ratio in cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
