"""The estimator's position error at the capture instant, per ranked scenario, on validation
seeds: what the capture envelope's tolerance is chosen from (docs/capture_envelope.md).

    python scripts/estimator_error_at_capture.py                 # 200 validation seeds each
    python scripts/estimator_error_at_capture.py --seeds 50 --scenarios paper grasp

    python scripts/estimator_error_at_capture.py --tolerance 0.005 --v-max 0.05 --hold 0.3

Plays the paper's controller (``incremental_ik``) on the first ``--seeds`` validation seeds of
each scenario (never a published seed) and prints, per scenario, the median, 95th percentile and
largest |X_T estimated - X_T true| at the step whose end the episode captured, in mm, and the
same at the end of every step within 20 mm of the target (what an agent sees as it closes in),
under each scenario's own capture rule or the one given.
"""

from __future__ import annotations

import argparse

import numpy as np

from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.evaluation.running.rollout import run_episode
from capture_bench.task.scenarios import list_scenarios, load_scenario

NEAR = 0.02  # m: "closing in"


def errors(scenario: str, seeds: int, **envelope: float) -> tuple[list[float], list[float]]:
    """The estimate's position error (m) at each capture and at each step within NEAR, under
    the scenario's capture rule or ``envelope`` (``capture_tolerance``, ``v_max``, ``hold``)."""
    loaded = load_scenario(scenario)
    if envelope:
        capture = {k: envelope[k] for k in ("v_max", "hold") if k in envelope}
        tolerance = envelope.get("capture_tolerance", loaded.capture_tolerance)
        loaded = loaded.replace(capture=capture, capture_tolerance=tolerance)
    env = CaptureEnv(loaded)
    agent = make_agent("incremental_ik", env)
    at_capture, near = [], []
    try:
        for seed in list(loaded.validation_seeds)[:seeds]:
            record, trace = run_episode(
                env, agent, agent_name="incremental_ik", scenario=scenario, seed=seed, trace=True
            )
            assert trace is not None
            error = trace.position_error
            near += error[(trace.distance < NEAR) & np.isfinite(error)].tolist()
            if record.outcome == "captured" and np.isfinite(error[-1]):
                at_capture.append(float(error[-1]))
    finally:
        env.close()
    return at_capture, near


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=200, help="validation seeds per scenario")
    parser.add_argument("--scenarios", nargs="+", default=list_scenarios(camera="analytic"))
    parser.add_argument("--tolerance", type=float, help="capture_tolerance instead, m")
    parser.add_argument("--v-max", type=float, help="capture.v_max instead, m/s")
    parser.add_argument("--hold", type=float, help="capture.hold instead, s")
    args = parser.parse_args(argv)
    given = {"capture_tolerance": args.tolerance, "v_max": args.v_max, "hold": args.hold}
    envelope = {k: v for k, v in given.items() if v is not None}
    print("| scenario | captures | at capture: median | p95 | max | within 20 mm: median | p95 |")
    print("|---|---|---|---|---|---|---|")
    for name in args.scenarios:
        at_capture, near = errors(name, args.seeds, **envelope)
        a, n = 1e3 * np.asarray(at_capture), 1e3 * np.asarray(near)
        print(
            f"| {name} | {a.size} | {np.median(a):.1f} | {np.percentile(a, 95):.1f} | "
            f"{a.max():.1f} | {np.median(n):.1f} | {np.percentile(n, 95):.1f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
