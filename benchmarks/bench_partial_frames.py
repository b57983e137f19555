"""What the EKF should do with a rendered frame that misses some markers: update on the markers
seen, or treat the frame as lost (predict only). Both rules on the same validation seeds of the
rendered scenarios, with the paper's controller:

    python benchmarks/bench_partial_frames.py --seeds 40

Prints, per scenario and rule: episodes captured, the median ratio of capture time to the
physical limit, the share of steps with a partial frame, and the estimate's position error (RMS
and 95th percentile over every step with a valid estimate, mm). Validation seeds only (the
scenario's ``validation_seeds``): nothing here is chosen on a published seed.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.sensing.estimator import PARTIAL_FRAME_RULES
from capture_bench.task.scenarios import load_scenario


def play(scenario: str, rule: str, seeds: list[int]) -> dict[str, float]:
    env = CaptureEnv(scenario)
    env.engine.sides.estimators[0].partial_frames = rule
    captured, ratios, errors, partial, steps = 0, [], [], 0, 0
    try:
        for seed in seeds:
            obs, _ = env.reset(seed=seed)
            agent = make_agent("incremental_ik", env)
            done = False
            while not done:
                obs, _, terminated, truncated, info = env.step(agent.predict(obs)[0])
                done = terminated or truncated
                found = env.engine.sides.sides[0].camera_episode.last_detections
                steps += 1
                partial += found is not None and 0 < found.found.sum() < found.found.size
                if math.isfinite(info["estimate_position_error"]):
                    errors.append(info["estimate_position_error"])
            if info["is_success"]:
                captured += 1
                ratios.append(info["capture_time"] / info["physical_limit_time"])
    finally:
        env.close()
    e = 1000.0 * np.array(errors)
    return {
        "captured": captured,
        "episodes": len(seeds),
        "median ratio": float(np.median(ratios)) if ratios else math.nan,
        "partial frames %": 100.0 * partial / max(steps, 1),
        "error RMS mm": float(np.sqrt(np.mean(e**2))),
        "error p95 mm": float(np.percentile(e, 95)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=40, help="validation seeds per scenario")
    parser.add_argument("--scenarios", nargs="+", default=["paper_rendered", "grasp_rendered"])
    args = parser.parse_args()
    for name in args.scenarios:
        seeds = list(load_scenario(name).validation_seeds[: args.seeds])
        for rule in PARTIAL_FRAME_RULES:
            row = play(name, rule, seeds)
            cells = ", ".join(
                f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()
            )
            print(f"{name:16s} {rule:8s} {cells}", flush=True)


if __name__ == "__main__":
    main()
