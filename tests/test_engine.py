"""The episode engine (`capture_bench.engine.engine.EpisodeEngine`): rows stepped together or
apart, as index arrays or as the one row's slice, and the target-side strategies, give the same
episodes bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils import seeding

from capture_bench.engine.arm import ArmSide
from capture_bench.engine.cache import EpisodeCache
from capture_bench.engine.engine import EpisodeEngine
from capture_bench.engine.sides import EpisodeDraw, LiveSides, RecordedSides
from capture_bench.engine.task import CaptureTask
from capture_bench.task.scenarios import load_scenario

STEPS = 40


def _engine(task: CaptureTask, n: int, sides) -> EpisodeEngine:
    return EpisodeEngine(task, n, sides, ArmSide(task.features, task.description.arm))


def _draws(scenario: str, n: int) -> list[EpisodeDraw]:
    seeds = load_scenario(scenario).validation_seeds[:n]
    return [EpisodeDraw(int(s), seeding.np_random(int(s))[0]) for s in seeds]


def _actions(n: int) -> np.ndarray:
    return np.random.default_rng(3).uniform(-1, 1, (STEPS, n, 3))


def _snapshot(engine: EpisodeEngine) -> list[np.ndarray]:
    state = engine.state
    return [
        state.theta.copy(),
        state.x_e.copy(),
        state.distance.copy(),
        engine.steps.copy(),
        *(track.copy() for track in engine.tracks.values()),
    ]


def _assert_same(a: list[np.ndarray], b: list[np.ndarray]) -> None:
    for i, (x, y) in enumerate(zip(a, b, strict=True)):
        np.testing.assert_array_equal(x, y, err_msg=f"array {i}")


@pytest.mark.parametrize("scenario", ["paper", "noisy"])
def test_rows_stepped_together_or_one_at_a_time_are_the_same(scenario):
    """Three rows stepped in one call, or each in a call of its own (the batched filter, the
    arm's limits and the rule see other batches), end with the same arm, tracks and outcomes,
    bit for bit."""
    task = CaptureTask(scenario)
    n, actions = 3, _actions(3)
    engines = [_engine(task, n, RecordedSides(task, n, EpisodeCache(), False)) for _ in range(2)]
    for engine in engines:
        engine.begin(np.arange(n), engine.prepare(_draws(scenario, n)))
    together, apart = engines
    alive = np.ones(n, dtype=bool)
    for k in range(STEPS):
        rows = np.flatnonzero(alive)
        out = together.step(rows, actions[k, rows])
        for position, j in enumerate(rows.tolist()):
            alone = apart.step(np.array([j]), actions[k, [j]])
            assert alone.reward[0] == out.reward[position]
            assert alone.terminated[0] == out.terminated[position]
        alive[rows] = ~(out.terminated | out.truncated)
    _assert_same(_snapshot(together), _snapshot(apart))
    for engine in engines:
        engine.close()


def test_a_one_row_engine_steps_the_same_as_a_slice_or_an_index_array():
    """The single env's slice path (views) and the index-array path give the same floats."""
    task = CaptureTask("paper")
    actions = _actions(1)
    engines = [_engine(task, 1, LiveSides(task, 1)) for _ in range(2)]
    for engine in engines:
        engine.begin(np.zeros(1, dtype=np.intp), engine.prepare(_draws("paper", 1)))
    as_slice, as_rows = engines
    for k in range(STEPS):
        a = as_slice.step(slice(None), actions[k])
        b = as_rows.step(np.zeros(1, dtype=np.intp), actions[k])
        assert a.reward.tolist() == b.reward.tolist()
        np.testing.assert_array_equal(as_slice.observe(), as_rows.observe())
        if a.terminated[0] or a.truncated[0]:
            break
    _assert_same(_snapshot(as_slice), _snapshot(as_rows))
    for engine in engines:
        engine.close()


@pytest.mark.parametrize("scenario", ["paper", "noisy", "jitter"])
def test_live_and_recorded_sides_give_the_same_rows(scenario):
    """A side computed step by step (`LiveSides`) and one recorded at the start as the single env
    records it (`RecordedSides` with ``reference``) fill the same tracks from the same draws:
    frames, estimates, errors, NEES, reachability."""
    task = CaptureTask(scenario)
    n, actions = 2, _actions(2)
    live = _engine(task, n, LiveSides(task, n))
    recorded = _engine(task, n, RecordedSides(task, n, EpisodeCache(), True))
    rows = np.arange(n)
    for engine in (live, recorded):
        engine.begin(rows, engine.prepare(_draws(scenario, n)))
    alive = np.ones(n, dtype=bool)
    for k in range(STEPS):
        stepping = rows[alive]
        out = live.step(stepping, actions[k, stepping])
        recorded.step(stepping, actions[k, stepping])
        alive[stepping] = ~(out.terminated | out.truncated)
    played = [(i, int(k) + 1) for i, k in enumerate(live.steps.tolist())]
    live_rows = [track[i, :end] for track in live.tracks.values() for i, end in played]
    recorded_rows = [track[i, :end] for track in recorded.tracks.values() for i, end in played]
    _assert_same(live_rows, recorded_rows)
    _assert_same(_snapshot(live)[:4], _snapshot(recorded)[:4])
    for engine in (live, recorded):
        engine.close()
