"""``capture.hold``: a hold of 0 is the paper's eq. 20, the bound with a hold is the arrival
plus the hold, and the ``grasp`` scenario that uses it."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.evaluation.running.backends import EpisodeTask, close_envs, run_task
from capture_bench.evaluation.running.rollout import TIMING_COLUMNS
from capture_bench.task.scenarios import list_scenarios, load_scenario

EPISODES = Path(__file__).parents[1] / "reports" / "published" / "default" / "episodes.csv"
AGENTS = ("incremental_ik", "oracle")
SEEDS_PER_CELL = 2


def _committed() -> dict[tuple[str, str, int], dict[str, str]]:
    with open(EPISODES, newline="") as handle:
        return {(r["agent"], r["scenario"], int(r["seed"])): r for r in csv.DictReader(handle)}


def test_a_hold_of_zero_leaves_the_default_suites_episodes_unchanged():
    """Every scenario of the committed default report with hold 0: the first seeds of
    incremental_ik and the oracle give the committed episodes, field for field (floats to
    rounding: the report was computed on this machine's CPU from an earlier commit)."""
    committed = _committed()
    shipped = sorted({scenario for _, scenario, _ in committed} & set(list_scenarios()))
    scenarios = [name for name in shipped if load_scenario(name).capture.hold == 0.0]
    assert scenarios  # paper_eq20, the paper's eq. 20 as published
    compared = 0
    try:
        for scenario in scenarios:
            for agent in AGENTS:
                seeds = sorted(s for a, c, s in committed if (a, c) == (agent, scenario))
                for seed in seeds[:SEEDS_PER_CELL]:
                    row = run_task(EpisodeTask(agent, scenario, seed))[0].as_row()
                    want = committed[(agent, scenario, seed)]
                    for key, value in row.items():
                        if key in TIMING_COLUMNS:
                            continue
                        where = (agent, scenario, seed, key)
                        if isinstance(value, float):
                            expected = math.nan if want[key] == "" else float(want[key])
                            assert value == pytest.approx(
                                expected, rel=1e-6, abs=1e-9, nan_ok=True
                            ), where
                        else:
                            assert str(value) == want[key], where
                    compared += 1
    finally:
        close_envs()
    assert compared == len(scenarios) * len(AGENTS) * SEEDS_PER_CELL


def test_the_bound_with_a_hold_is_the_arrival_plus_the_hold():
    grasp = load_scenario("grasp")
    assert grasp.capture.hold > 0
    without = grasp.replace(capture={"hold": 0.0})
    finite = 0
    for seed in grasp.validation_seeds[:4]:
        bounds = []
        for scenario in (grasp, without):
            env = CaptureEnv(scenario, reuse_target_side=True)
            try:
                env.reset(seed=seed)
                bounds.append(env.physical_limit())
            finally:
                env.close()
        held, instant = bounds
        assert held.hold == grasp.capture.hold and instant.hold == 0.0
        assert held.arrival == pytest.approx(instant.time, abs=1e-12)
        if math.isfinite(instant.time):
            finite += 1
            assert held.time == instant.time + grasp.capture.hold
            np.testing.assert_array_equal(held.theta, instant.theta)
    assert finite >= 3


def test_grasp_is_shipped_in_the_default_suite_with_its_own_seeds():
    from capture_bench.evaluation.running.suites import load_suite

    assert "grasp" in list_scenarios()
    assert load_suite("default").scenarios == ("all",)  # every analytic shipped scenario
    grasp = load_scenario("grasp")
    assert grasp.env_id == "CaptureBench/Grasp-v1"
    held_out = range(grasp.seeds.evaluation_start, grasp.validation_seeds.stop)

    def overlap(a: range, b: range) -> bool:
        return a.start < b.stop and b.start < a.stop

    for name in list_scenarios():
        other = load_scenario(name)
        if name not in ("grasp", "grasp_rendered"):  # its rendered twin shares its seeds
            theirs = range(other.seeds.evaluation_start, other.validation_seeds.stop)
            assert not overlap(held_out, theirs), name
        assert not overlap(held_out, other.training_seeds), name
