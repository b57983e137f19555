"""Time the evaluation's recording of target sides: a live `TargetSide` filled step by step
(the single env's way, a one-row estimator) against `record_episodes` of the same seeds (every
step at once, the episodes' estimators as rows of one, the first frames' cold photogrammetry as
one batch), and check the two are equal track for track.

    python benchmarks/bench_recording.py                 # 60 seeds of every scenario
    python benchmarks/bench_recording.py --seeds 20 --scenarios paper tumbling

Each scenario's seeds are recorded one way, then the other, in this process, the memo of cold
solves emptied before each (as a fresh evaluation worker starts). Prints seconds per scenario and
in all, and exits 1 if any track of any row differs.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import fields

import numpy as np
from gymnasium.utils import seeding

from capture_bench.engine.task import CaptureTask
from capture_bench.sensing import photogrammetry
from capture_bench.sensing.estimator import TargetEstimator
from capture_bench.task.recording import RecordedEpisode, record_episodes
from capture_bench.task.scenarios import list_scenarios
from capture_bench.task.target_side import TargetSide

#: Every per-step track of a recording (not the plan, the bound or a continuation).
TRACKS = tuple(
    f.name for f in fields(RecordedEpisode) if f.name not in ("plan", "bound", "continuation")
)


def step_by_step(task: CaptureTask, seeds: range) -> list[RecordedEpisode]:
    """Each seed's live side filled to its time limit before the next is drawn."""
    sc = task.scenario
    estimator = TargetEstimator(
        1, task.camera.model, task.features, source=sc.estimator.source, **sc.estimator_settings()
    )
    episodes = []
    for seed in seeds:
        rng = seeding.np_random(seed)[0]
        side = TargetSide.draw(sc, task.camera, estimator, task.features, rng)
        episodes.append(side.through(side.episode.time.size - 1))
    return episodes


def at_once(task: CaptureTask, seeds: range) -> list[RecordedEpisode]:
    """The seeds' episodes recorded together."""
    rngs = [seeding.np_random(seed)[0] for seed in seeds]
    return record_episodes(task.scenario, task.camera, task.features, task.description, rngs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=60, help="seeds per scenario")
    parser.add_argument("--scenarios", nargs="+", default=list_scenarios(camera="analytic"))
    args = parser.parse_args()
    totals = [0.0, 0.0]
    differing = 0
    print(f"{'scenario':10s} {'step by step s':>15s} {'record_episodes s':>18s}")
    for name in args.scenarios:
        task = CaptureTask(name)
        seeds = range(args.seeds)
        seconds, results = [], []
        for way in (step_by_step, at_once):
            photogrammetry.clear_solve_cache()
            start = time.perf_counter()
            results.append(way(task, seeds))
            seconds.append(time.perf_counter() - start)
        totals = [t + s for t, s in zip(totals, seconds, strict=True)]
        for a, b in zip(*results, strict=True):
            differing += sum(
                not np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True) for f in TRACKS
            )
        print(f"{name:10s} {seconds[0]:15.2f} {seconds[1]:18.2f}")
    print(f"{'all':10s} {totals[0]:15.2f} {totals[1]:18.2f}")
    print("every track equal" if not differing else f"{differing} tracks differ")
    return 1 if differing else 0


if __name__ == "__main__":
    sys.exit(main())
