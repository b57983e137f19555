"""When the filter starts with and without three-point initialisation, on validation seeds.

Runs one agent on a scenario's validation seeds twice, in the single env: with photogrammetry
starts only (``estimator.min_init_markers: 4``) and with three-point starts (3), whatever the
scenario file says, and without the agent's acquisition (the filter's start alone). Prints, per
seed and setting, the first step with a valid estimate, the position error of that estimate and
the outcome.

    python scripts/three_point_start.py --scenario paper_rendered --agent incremental_ik --seeds 10
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.task.scenarios import Scenario, load_scenario


def episode(scenario: Scenario, agent_name: str, seed: int) -> dict[str, Any]:
    """One episode's start of the filter and its outcome, the agent without acquisition."""
    env = CaptureEnv(scenario)
    agent = make_agent(agent_name, env)
    if hasattr(agent, "acquisition"):
        agent.acquisition = None
    if hasattr(agent, "seed"):
        agent.seed(seed)
    agent.reset()
    obs, info = env.reset(seed=seed)
    first_valid, first_error, step = None, math.nan, 0
    done = False
    while not done:
        action, _ = agent.predict(obs, deterministic=True)
        obs, _, terminated, truncated, info = env.step(action)
        step += 1
        if first_valid is None and info.get("estimator_status") in ("ok", "predicting"):
            first_valid, first_error = step, float(info["estimate_position_error"])
        done = terminated or truncated
    env.close()
    return {
        "first_valid": first_valid,
        "first_error_mm": 1e3 * first_error,
        "steps": step,
        "outcome": "capture" if info["is_success"] else str(info["failure"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_rendered")
    parser.add_argument("--agent", default="incremental_ik")
    parser.add_argument("--seeds", type=int, default=10, help="the first N validation seeds")
    args = parser.parse_args()
    shipped = load_scenario(args.scenario)
    seeds = list(shipped.validation_seeds)[: args.seeds]
    results: dict[int, dict[int, dict[str, Any]]] = {4: {}, 3: {}}
    for markers in (4, 3):
        scenario = shipped.replace(estimator={"min_init_markers": markers})
        for seed in seeds:
            results[markers][seed] = episode(scenario, args.agent, seed)
    print(f"{args.scenario}, {args.agent}, validation seeds {seeds[0]}..{seeds[-1]}")
    print("seed | first valid step (4 / 3) | first error mm (4 / 3) | outcome (4 / 3)")
    for seed in seeds:
        a, b = results[4][seed], results[3][seed]
        print(
            f"{seed} | {a['first_valid']} / {b['first_valid']} | "
            f"{a['first_error_mm']:.1f} / {b['first_error_mm']:.1f} | "
            f"{a['outcome']} / {b['outcome']}"
        )
    for markers in (4, 3):
        starts = [r["first_valid"] for r in results[markers].values()]
        print(
            f"min_init_markers={markers}: started in {sum(s is not None for s in starts)} of "
            f"{len(starts)}; median first valid step "
            f"{np.median([s for s in starts if s is not None]) if any(starts) else None}"
        )


if __name__ == "__main__":
    main()
