"""A live target side (`TargetSide`, a one-row estimator, filled step by step as the single env
fills it) is the recording of the same generator ahead (`record_episodes`, every step at once,
many episodes together): the same draws, the same numbers, every track, every row."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest
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


def _live(task: CaptureTask, seeds: range, stretches: tuple[int, ...] = ()):
    """Each seed drawn and filled before the next is drawn, as `LiveSides` draws them (one
    one-row estimator, which each draw resets): filled through the steps ``stretches`` in turn,
    then to the time limit. The episodes and the generators after them."""
    sc = task.scenario
    estimator = TargetEstimator(
        1, task.camera.model, task.features, source=sc.estimator.source, **sc.estimator_settings()
    )
    episodes, rngs = [], []
    for seed in seeds:
        rng = seeding.np_random(seed)[0]
        side = TargetSide.draw(sc, task.camera, estimator, task.features, rng)
        for k in stretches:
            side.through(k)
            assert side.filled == k + 1
        episodes.append(side.through(side.episode.time.size - 1))
        assert side.complete
        rngs.append(rng)
    return episodes, rngs


@pytest.mark.parametrize("name", list_scenarios())
def test_a_live_side_filled_step_by_step_is_the_recording_of_its_seed(name):
    """Every track of every row bit for bit (true states, frames, estimates, errors, NEES,
    reachability), with the cold photogrammetry solved one image at a time live and as a batch
    in the recording; and each generator left in the same state."""
    task = CaptureTask(name)
    seeds = range(2_000, 2_006)
    photogrammetry.clear_solve_cache()
    live, live_rngs = _live(task, seeds)
    photogrammetry.clear_solve_cache()
    rngs = [seeding.np_random(s)[0] for s in seeds]
    recorded = record_episodes(task.scenario, task.camera, task.features, task.description, rngs)
    for want, got in zip(live, recorded, strict=True):
        assert got.continuation is None and want.estimate_valid.any()
        for track in TRACKS:
            np.testing.assert_array_equal(getattr(got, track), getattr(want, track), track)
    for a, b in zip(live_rngs, rngs, strict=True):
        assert a.bit_generator.state == b.bit_generator.state


def test_a_side_filled_in_stretches_is_the_side_filled_at_once():
    """A live side the env has filled part of keeps its rows and fills the rest in order."""
    task = CaptureTask("noisy")
    (full,), _ = _live(task, range(7, 8))
    (parts,), _ = _live(task, range(7, 8), stretches=(0, 5, 6, 30))
    for track in TRACKS:
        np.testing.assert_array_equal(getattr(parts, track), getattr(full, track), track)
