"""Time the evaluation's recording of target sides: step by step (the live single env's way)
against `TargetSide.record_many` (every step at once, the first frames' cold
photogrammetry as one batch), and check the two are equal field for field.

    python benchmarks/bench_recording.py                 # 60 seeds of every scenario
    python benchmarks/bench_recording.py --seeds 20 --scenarios paper tumbling

Each scenario's seeds are recorded one way, then the other, in this process, the memo of cold
solves emptied before each (as a fresh evaluation worker starts). Prints seconds per scenario and
in all, and exits 1 if any field of any row differs.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from gymnasium.utils import seeding

from capture_bench.engine.task import scenario_camera
from capture_bench.sensing import photogrammetry
from capture_bench.sensing.estimator import TargetEstimator
from capture_bench.task.recording import STEP_TRACKS
from capture_bench.task.scenarios import list_scenarios, load_scenario
from capture_bench.task.target_side import TargetSide

FIELDS = (*STEP_TRACKS, "rotation", "images")  # every recorded track


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=60, help="seeds per scenario")
    parser.add_argument("--scenarios", nargs="+", default=list_scenarios(camera="analytic"))
    args = parser.parse_args()
    totals = [0.0, 0.0]
    differing = 0
    print(f"{'scenario':10s} {'step by step s':>15s} {'record_many s':>14s}")
    for name in args.scenarios:
        scenario = load_scenario(name)
        camera, features = scenario_camera(scenario)
        estimator = TargetEstimator(
            camera.model, features, source=scenario.estimator.source,
            **scenario.estimator_settings(),
        )  # fmt: skip

        def side(seed: int) -> TargetSide:
            rng = seeding.np_random(seed)[0]
            return TargetSide.draw(scenario, camera, estimator, features, rng)  # noqa: B023

        seeds = range(args.seeds)
        photogrammetry.clear_solve_cache()
        start = time.perf_counter()
        alone = []
        for seed in seeds:
            one = side(seed)
            alone.append(one.through(one.episode.time.size - 1))
        step_by_step = time.perf_counter() - start
        photogrammetry.clear_solve_cache()
        start = time.perf_counter()
        together = TargetSide.record_many([side(seed) for seed in seeds])
        at_once = time.perf_counter() - start
        totals[0] += step_by_step
        totals[1] += at_once
        for a, b in zip(alone, together, strict=True):
            differing += sum(
                not np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True) for f in FIELDS
            )
        print(f"{name:10s} {step_by_step:15.2f} {at_once:14.2f}")
    print(f"{'all':10s} {totals[0]:15.2f} {totals[1]:14.2f}")
    print("every field equal" if not differing else f"{differing} fields differ")
    return 1 if differing else 0


if __name__ == "__main__":
    sys.exit(main())
