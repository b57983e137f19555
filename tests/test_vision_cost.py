"""What vision costs: the truth-fed twins (the same targets, seeds and capture rule, fed the true
state), which episodes a suite plays on them, and the report's gaps against synthetic records
whose answer is known."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from test_evaluation_metrics import record
from test_vision_report import _data, _images

from capture_bench.evaluation.errors import SuiteError
from capture_bench.evaluation.pipeline import EvaluationConfig, plan_evaluation, twin_tasks
from capture_bench.evaluation.reporting import vision_cost
from capture_bench.evaluation.reporting.report import TWINS_CSV, markdown, write_report
from capture_bench.evaluation.reporting.vision import rendered_twins, vision_comparisons
from capture_bench.evaluation.running.agents_loading import resolve_agent
from capture_bench.evaluation.running.backends import (
    EpisodeTask,
    close_envs,
    make_env,
    run_tasks,
)
from capture_bench.evaluation.running.suites import load_suite
from capture_bench.task.scenarios import (
    SCENARIO_DIR,
    ConfigError,
    list_scenarios,
    load_scenario,
)

LOST = (2, 5, 11)  # seeds the estimate-fed agent fails on each scenario
SCENARIOS = ("paper", "grasp")


def _without(scenario, *keys: str) -> dict:
    data = dataclasses.asdict(scenario)
    for key in keys:
        data.pop(key)
    return data


@pytest.mark.parametrize("name", list_scenarios(camera="analytic"))
def test_a_truth_twin_is_its_scenario_fed_the_true_state(name):
    scenario, twin = load_scenario(name), load_scenario(f"{name}_truth")
    assert not (SCENARIO_DIR / f"{name}_truth.yaml").exists()  # derived in code
    assert twin.name == f"{name}_truth" and twin.estimator.source == "truth"
    assert twin.evaluation_seeds == scenario.evaluation_seeds
    assert _without(twin, "name", "estimator") == _without(scenario, "name", "estimator")
    assert dataclasses.replace(twin.estimator, source="ekf") == scenario.estimator


@pytest.mark.parametrize("name", ["paper_truth_truth", "nothing_truth", "../paper_truth"])
def test_a_name_no_shipped_scenario_twins_is_unknown(name):
    with pytest.raises(ConfigError, match="unknown scenario"):
        load_scenario(name)


def test_a_truth_twin_plays_the_same_targets():
    """The physical limit is computed from the target's true motion: equal seed by seed."""
    tasks = [EpisodeTask("incremental_ik", s, seed) for s in ("grasp", "grasp_truth") for seed in
             load_scenario("grasp").evaluation_seeds[:3]]  # fmt: skip
    try:
        records = run_tasks(tasks)
    finally:
        close_envs()
    ekf, truth = records[:3], records[3:]
    assert [r.scenario for r in truth] == ["grasp_truth"] * 3
    assert [r.seed for r in ekf] == [r.seed for r in truth]
    assert [r.physical_limit_time for r in ekf] == [r.physical_limit_time for r in truth]
    assert all(r.position_rmse == 0.0 for r in truth)  # fed the truth: no estimation error


def test_a_truth_twin_makes_its_single_env():
    env = make_env("grasp_truth")
    try:
        scenario = env.unwrapped.scenario
        assert (scenario.name, scenario.estimator.source) == ("grasp_truth", "truth")
    finally:
        env.close()


def test_rendered_twins_hold_the_capture_envelope_of_their_scenarios():
    pairs = rendered_twins(list_scenarios())
    assert ("paper", "paper_rendered") in pairs and ("grasp", "grasp_rendered") in pairs
    for name, twin in pairs:
        scenario, rendered = load_scenario(name), load_scenario(twin)
        assert rendered.capture == scenario.capture
        assert rendered.capture_tolerance == scenario.capture_tolerance
        assert rendered.ranked == scenario.ranked
        other = ("name", "description", "camera", "estimator")
        assert _without(rendered, *other) == _without(scenario, *other)
        # Only the vision differs: the same camera pose and intrinsics seen through the rendered
        # image (a lens, a calibration error, a detector), and a filter that may start from
        # three markers; the estimator's process noise is the same.
        geometry = ("position", "look_at", "focal_length", "pixel_pitch", "resolution")
        for key in geometry:
            assert getattr(rendered.camera, key) == getattr(scenario.camera, key), key
        estimator = dataclasses.replace(rendered.estimator, min_init_markers=4)
        assert estimator == scenario.estimator


def _suite(**changes):
    return dataclasses.replace(load_suite("quick"), **changes)


def test_the_suite_plays_the_truth_twins_of_the_ranked_scenarios_for_estimate_fed_agents():
    specs = [resolve_agent(a) for a in ("incremental_ik", "random", "hold", "oracle")]
    seeds = {"paper": [1, 2, 3], "tumbling": [4, 5, 6], "paper_eq20": [7, 8, 9]}
    suite = _suite(
        truth_twins=True,
        rendered_twins=("paper_rendered", "grasp_rendered"),
        rendered_agents=("incremental_ik", "oracle"),
        rendered_episodes=2,
    )
    tasks = twin_tasks(suite, specs, list(seeds), seeds)
    got = [(t.agent, t.scenario, t.seed) for t in tasks]
    assert got == [
        ("incremental_ik", "paper_truth", 1),
        ("incremental_ik", "paper_truth", 2),
        ("incremental_ik", "paper_truth", 3),
        ("incremental_ik", "tumbling_truth", 4),
        ("incremental_ik", "tumbling_truth", 5),
        ("incremental_ik", "tumbling_truth", 6),
        # paper_eq20 is not ranked; grasp is not played, so neither is grasp_rendered
        ("incremental_ik", "paper_rendered", 1),
        ("incremental_ik", "paper_rendered", 2),
        ("oracle", "paper_rendered", 1),
        ("oracle", "paper_rendered", 2),
    ]
    assert twin_tasks(_suite(), specs, list(seeds), seeds) == []


def test_the_default_suite_plays_the_twins_unranked():
    suite = load_suite("default")
    assert suite.truth_twins and suite.scenarios == ("all",)
    assert suite.rendered_twins == ("paper_rendered", "grasp_rendered")
    assert suite.rendered_agents == ("incremental_ik", "pure_pursuit", "dagger-dls-all")
    assert 1 <= suite.rendered_episodes <= suite.episodes


def _write_suite(tmp_path: Path, extra: str) -> str:
    path = tmp_path / "mine.yaml"
    path.write_text(
        "agents: [incremental_ik]\nscenarios: [paper]\nepisodes: 2\nvideos: false\n" + extra
    )
    return str(path)


@pytest.mark.parametrize(
    "extra, message",
    [
        ("rendered_twins: [paper_rendered]\n", "needs rendered_agents, rendered_episodes too"),
        (
            "rendered_twins: [drift]\nrendered_agents: [incremental_ik]\nrendered_episodes: 1\n",
            "key 'rendered_twins': 'drift' is not valid",
        ),
        (
            "rendered_twins: [paper_rendered]\nrendered_agents: [dls]\nrendered_episodes: 1\n",
            "key 'rendered_agents': 'dls' is not valid; expected one of the suite's agents",
        ),
        ("truth_twins: 3\n", "truth_twins"),
    ],
)
def test_bad_twin_keys_name_the_key(tmp_path, extra, message):
    with pytest.raises(SuiteError, match=message) as caught:
        plan_evaluation(EvaluationConfig(suite=_write_suite(tmp_path, extra), out=tmp_path))
    assert "\n" not in str(caught.value)


def _pairs(agent: str = "incremental_ik", seeds: int = 20) -> tuple[list, list]:
    """On each of `SCENARIOS`: estimate-fed, ``agent`` fails `LOST` and captures seed s at
    1.5 + 0.01 s; truth-fed it captures every seed at 1.2 + 0.01 s (ratio = time)."""
    estimate, truth = [], []
    for scenario in SCENARIOS:
        for seed in range(seeds):
            fed = None if seed in LOST else 1.5 + 0.01 * seed
            estimate.append(record(agent, seed, fed, scenario=scenario))
            truth.append(record(agent, seed, 1.2 + 0.01 * seed, scenario=f"{scenario}_truth"))
    return estimate, truth


def test_the_perception_and_control_gaps_are_computed_from_the_pairs():
    estimate, truth = _pairs()
    (c,) = vision_cost.perception_comparisons(estimate, truth, SCENARIOS)
    assert (c.subject, c.a, c.b, c.seeds) == ("incremental_ik", "estimate-fed", "truth-fed", 40)
    assert (c.only_a, c.only_b, c.both_captured) == (0, 6, 34)
    # perception gap: captures the estimate loses, +6/40, and the time it costs, -0.3
    assert c.capture_rate_difference.value == pytest.approx(6 / 40)
    assert c.capture_rate_difference.low > 0
    assert c.ratio_difference.value == pytest.approx(-0.3)
    # control gap: the truth-fed median ratio over the 40 truth-fed captures
    assert c.ratio_median_b.value == pytest.approx(np.median(1.2 + 0.01 * np.arange(20)))
    assert c.ratio_median_b.low <= c.ratio_median_b.value <= c.ratio_median_b.high
    assert c.unpaired_a == c.unpaired_b == ()
    rates = vision_cost.truth_fed_rates(truth, SCENARIOS)
    assert rates == {"incremental_ik": 1.0}
    assert vision_cost.truth_fed_rates(truth, ("paper",)) == {"incremental_ik": 1.0}


def test_a_scenario_not_ranked_counts_in_no_gap():
    estimate, truth = _pairs()
    (c,) = vision_cost.perception_comparisons(estimate, truth, ("paper",))
    assert c.seeds == 20 and c.capture_rate_difference.value == pytest.approx(3 / 20)


def test_the_rendered_gaps_are_paired_over_the_rendered_seeds():
    estimate, truth = _pairs()
    rendered = [record("incremental_ik", s, 2.0, scenario="paper_rendered") for s in range(5)]
    (c,) = vision_cost.rendered_comparisons([*truth, *rendered])
    assert (c.a, c.b, c.seeds) == ("paper_rendered", "paper_truth", 5)
    assert c.unpaired_a == c.unpaired_b == ()
    assert c.ratio_difference.value == pytest.approx(np.median(1.2 + 0.01 * np.arange(5)) - 2.0)
    # rendered vs analytic: the analytic episodes kept are those of the rendered seeds
    kept = vision_cost.vision_records(estimate, [*truth, *rendered])
    (v,) = vision_comparisons(kept)
    assert (v.a, v.b, v.seeds, v.unpaired_a) == ("paper", "paper_rendered", 5, ())
    assert sum(r.scenario == "grasp" for r in kept) == 20  # no rendered twin: all kept


def test_the_report_shows_the_truth_fed_column_and_the_gaps(tmp_path):
    estimate, truth = _pairs()
    other, _ = _pairs("pure_pursuit")  # played no truth-fed twin
    rendered = [record("incremental_ik", s, 2.0, scenario="paper_rendered") for s in range(5)]
    data = dataclasses.replace(_data(estimate + other), twin_records=[*truth, *rendered])
    md = markdown(data)
    lines = md.splitlines()
    header = next(line for line in lines if line.startswith("| rank | agent |"))
    assert "| mean capture rate | truth-fed mean capture rate |" in header
    rows = {line.split(" | ")[1]: line for line in lines if line.startswith("| ") and
            " | 0.850 | " in line}  # fmt: skip
    assert "| 0.850 | 1.000 |" in rows["incremental_ik"]
    assert "| 0.850 | — |" in rows["pure_pursuit"]
    assert f"## {vision_cost.TITLE}" in lines and vision_cost.TEXT in lines
    assert "### Analytic camera, over the ranked scenarios (paper, grasp)" in lines
    assert "### Rendered camera: paper_rendered against paper_truth" in lines
    assert "## Rendered vs analytic vision" in lines
    target = write_report(data, tmp_path, images=_images(data))
    payload = json.loads((target / "results.json").read_text())
    pooled, rendered_row = payload["vision_cost"]
    assert (pooled["agent"], pooled["camera"], pooled["truth"]) == (
        "incremental_ik",
        "estimate-fed",
        "truth-fed",
    )
    assert pooled["capture_rate_difference"] == pytest.approx(6 / 40)
    assert pooled["ratio_difference"] == pytest.approx(-0.3)
    assert (rendered_row["camera"], rendered_row["seeds"]) == ("paper_rendered", 5)
    entry = {r["agent"]: r for r in payload["ranking"]}
    assert entry["incremental_ik"][vision_cost.RANKING_KEY] == 1.0
    assert vision_cost.RANKING_KEY not in entry["pure_pursuit"]
    assert (target / TWINS_CSV).read_text().count("\n") == 1 + len(truth) + len(rendered)
    assert "paper_truth" not in (target / "episodes.csv").read_text()  # not ranked


def test_a_report_without_twins_is_as_before(tmp_path):
    estimate, _ = _pairs()
    data = _data(estimate)
    md = markdown(data)
    assert vision_cost.TITLE not in md and vision_cost.COLUMN not in md
    target = write_report(data, tmp_path, images=_images(data))
    assert not (target / TWINS_CSV).exists()
    assert "vision_cost" not in json.loads((target / "results.json").read_text())
