"""rliable's statistics (Agarwal et al. 2021) in the report and the learning curves: the numbers
equal a direct call of the rliable library on the same score matrices with the same seed; the
leaderboard's matrices are episodes x scenarios built from the records; the report's section and
results.json key appear where the matrices can be built and say why not elsewhere; the curves'
numbers are rliable's over the runs' training seeds; a validations.csv without ``mean_score``
stays readable."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from rliable import library, metrics
from test_evaluation_metrics import _report_data, record
from test_vision_report import _data

from capture_bench import rliable_stats
from capture_bench.evaluation.reporting import rliable_report
from capture_bench.evaluation.reporting.report import (
    figure_names,
    markdown,
    rliable_numbers,
    write_report,
)
from capture_bench.evaluation.reporting.summary import probability_of_improvement, score
from capture_bench.task.score import episode_score
from capture_bench.training.curves import seed_statistics

REPS = 40  # small: the equalities hold at any number of resamples


def _direct_aggregates(matrix: np.ndarray, reps: int, seed: int = rliable_stats.SEED):
    """rliable itself, as its README calls it: (point estimates, 2 x 3 intervals)."""

    def aggregates(x):
        return np.array(
            [
                metrics.aggregate_iqm(x),
                metrics.aggregate_optimality_gap(x, 1.0),
                metrics.aggregate_mean(x),
            ]
        )

    with rliable_stats.seeded_global_numpy(seed):  # np.random.seed(seed), undone after
        points, intervals = library.get_interval_estimates({"a": matrix}, aggregates, reps=reps)
    return points["a"], intervals["a"]


def _direct_improvement(x: np.ndarray, y: np.ndarray, reps: int, seed: int = rliable_stats.SEED):
    with rliable_stats.seeded_global_numpy(seed):
        points, intervals = library.get_interval_estimates(
            {"x,y": (x, y)}, metrics.probability_of_improvement, reps=reps
        )
    return points["x,y"], np.ravel(intervals["x,y"])


def _scores(rng: np.random.Generator, runs: int, tasks: int) -> np.ndarray:
    """Scores like the benchmark's: failures at 0, captures in (0.3, 1], many ties."""
    captured = rng.random((runs, tasks)) < 0.8
    return np.where(captured, np.round(rng.uniform(0.3, 1.0, (runs, tasks)), 2), 0.0)


def test_the_aggregates_equal_rliables_on_the_same_scores_and_seed():
    rng = np.random.default_rng(3)
    matrices = {"a": _scores(rng, 30, 4), "b": _scores(rng, 7, 4), "c": _scores(rng, 2, 1)}
    before = np.random.get_state()  # noqa: NPY002  (the global state rliable draws from)
    got = rliable_stats.aggregate_estimates(matrices, reps=REPS)
    after = np.random.get_state()  # noqa: NPY002
    assert np.array_equal(before[1], after[1]) and before[2] == after[2]  # the caller's, restored
    for name, matrix in matrices.items():
        points, intervals = _direct_aggregates(matrix, REPS)
        for k, figure in enumerate(rliable_stats.AGGREGATES):
            estimate = got[name][figure]
            assert estimate.value == points[k]
            assert (estimate.low, estimate.high) == (intervals[0, k], intervals[1, k])
    assert rliable_stats.aggregate_estimates(matrices, reps=REPS) == got  # reproducible
    iqm = got["a"]["iqm"].value
    assert iqm == pytest.approx(float(np.mean(np.sort(matrices["a"], axis=None)[30:90])))


def test_the_profiles_equal_rliables_default_score_distribution():
    rng = np.random.default_rng(4)
    matrices = {"a": _scores(rng, 20, 3), "b": _scores(rng, 5, 3)}
    taus = np.linspace(0.0, 1.0, 11)
    got = rliable_stats.performance_profiles(matrices, taus, reps=REPS)
    for name, matrix in matrices.items():
        with rliable_stats.seeded_global_numpy(rliable_stats.SEED):
            profiles, bands = library.create_performance_profile({name: matrix}, taus, reps=REPS)
        assert np.array_equal(got[name].share, profiles[name])
        assert np.array_equal(got[name].low, bands[name][0])
        assert np.array_equal(got[name].high, bands[name][1])
        np.testing.assert_array_equal(
            got[name].share, [np.mean(matrix > tau) for tau in taus]
        )  # the definition itself


def test_the_probability_of_improvement_equals_rliables():
    rng = np.random.default_rng(5)
    x, y, z = _scores(rng, 25, 3), _scores(rng, 12, 3), _scores(rng, 25, 3)
    for a, b in ((x, y), (y, x), (x, x), (x, z), (np.zeros((4, 3)), np.zeros((6, 3)))):
        assert rliable_stats.probability_of_improvement(a, b) == (
            metrics.probability_of_improvement(a, b)
        )
    got = rliable_stats.improvement_probabilities(
        [("x", "y"), ("z", "x")], {"x": x, "y": y, "z": z}, reps=REPS
    )
    for (first, second), (a, b) in {("x", "y"): (x, y), ("z", "x"): (z, x)}.items():
        point, band = _direct_improvement(a, b, REPS)
        estimate = got[(first, second)]
        assert (estimate.value, estimate.low, estimate.high) == (point, band[0], band[1])
    with pytest.raises(ValueError, match="tasks"):
        rliable_stats.improvement_probabilities([("x", "w")], {"x": x, "w": x[:, :2]}, reps=2)


def _equal_counts(seeds: int = 8) -> list:
    """Three agents x two scenarios x ``seeds`` seeds (the oracle privileged), records shuffled
    so that the matrices' row order is the seeds', not the records'."""
    rng = np.random.default_rng(6)
    recs = []
    for scenario in ("paper", "drift"):
        for seed in range(seeds):
            for agent, base in (("incremental_ik", 2.0), ("fast", 1.4), ("oracle", 1.0)):
                time = None if rng.random() < 0.2 else base + 0.1 * seed
                recs.append(record(agent, 100 + seed, time, scenario=scenario))
    order = rng.permutation(len(recs))
    return [recs[i] for i in order]


def test_the_score_matrices_are_episodes_by_scenarios_in_seed_order():
    recs = _equal_counts()
    matrices, scenarios = rliable_report.score_matrices(recs, ["fast", "incremental_ik", "oracle"])
    assert list(matrices) == ["fast", "incremental_ik", "oracle"]
    assert set(scenarios) == {"paper", "drift"}
    for agent, matrix in matrices.items():
        assert matrix.shape == (8, 2)
        for j, scenario in enumerate(scenarios):
            mine = sorted((r for r in recs if r.agent == agent and r.scenario == scenario),
                          key=lambda r: r.seed)  # fmt: skip
            assert matrix[:, j].tolist() == [score(r) for r in mine]
    captured = next(r for r in recs if r.captured)
    assert score(captured) == 1.0 / captured.ratio == episode_score(True, captured.ratio)
    assert episode_score(False, math.nan) == 0.0 and episode_score(True, math.nan) == 1.0

    uneven = recs + [record("fast", 999, 1.0, scenario="paper")]
    with pytest.raises(ValueError, match="fast played") as refused:
        rliable_report.score_matrices(uneven)
    assert "9 on paper" in str(refused.value) and "8 on drift" in str(refused.value)
    absent = [r for r in recs if not (r.agent == "oracle" and r.scenario == "drift")]
    assert "oracle has no episode on drift" in rliable_report.unavailable(absent, ["oracle"])


def test_the_reports_numbers_are_rliables_on_the_records(tmp_path):
    data = _data(_equal_counts())
    section, why = rliable_numbers(data)
    assert why is None and section is not None
    agents = [r.agent for r in data.ranking]
    assert section.agents == agents and section.reference == "incremental_ik"
    matrices, _ = rliable_report.score_matrices(data.records, agents)
    for agent in agents:
        points, intervals = _direct_aggregates(matrices[agent], rliable_stats.REPS)
        for k, figure in enumerate(rliable_stats.AGGREGATES):
            estimate = section.aggregates[agent][figure]
            assert (estimate.value, estimate.low, estimate.high) == (
                points[k],
                intervals[0, k],
                intervals[1, k],
            )
    assert "incremental_ik" not in section.improvement
    matrix = probability_of_improvement(data.records, agents)  # the summary's hand-made one
    ref = agents.index("incremental_ik")
    for agent, estimate in section.improvement.items():
        point, band = _direct_improvement(
            matrices[agent], matrices["incremental_ik"], rliable_stats.REPS
        )
        assert (estimate.value, estimate.low, estimate.high) == (point, band[0], band[1])
        assert estimate.value == pytest.approx(matrix[agents.index(agent), ref], abs=1e-12)

    target = write_report(data, tmp_path)
    md = (target / "leaderboard.md").read_text()
    html = (target / "leaderboard.html").read_text()
    for page in (md, html):
        assert rliable_report.TITLE in page and "unit of replication is the episode" in page
    assert (target / rliable_report.FIGURE).read_bytes().startswith(b"\x89PNG")
    assert f"]({rliable_report.FIGURE})" in md  # ![what it shows](file)
    assert rliable_report.FIGURE in figure_names(data)
    payload = json.loads((target / "results.json").read_text())["rliable"]
    assert payload["unit_of_replication"].startswith("episode")
    rows = {row["agent"]: row for row in payload["agents"]}
    assert set(rows) == set(agents) and rows["fast"]["episodes_per_scenario"] == 8
    iqm = section.aggregates["fast"]["iqm"]
    assert rows["fast"]["iqm"] == {"value": iqm.value, "low": iqm.low, "high": iqm.high}
    assert rows["incremental_ik"]["probability_of_improvement_over_reference"] is None
    line = next(x for x in md.splitlines() if x.startswith("| oracle (privileged) |"))
    assert len(line.split(" | ")) == len(rliable_report.HEADER)


def test_records_that_make_no_matrix_leave_the_section_with_its_reason(tmp_path):
    data = _report_data()  # fast and incremental_ik play 12 seeds on paper, 3 on drift
    assert rliable_report.FIGURE not in figure_names(data)
    md = markdown(data)
    assert f"## {rliable_report.TITLE}" in md
    assert "Left out: every agent must play every scenario on the same number of seeds" in md
    target = write_report(data, tmp_path)
    payload = json.loads((target / "results.json").read_text())
    assert "same number of seeds" in payload["rliable"]["left_out"]
    assert not (target / rliable_report.FIGURE).exists()


def test_the_curves_statistics_are_rliables_over_the_training_seeds():
    finals = {"ppo": {0: 0.41, 1: 0.62, 2: 0.55}, "sac": {2: 0.7, 0: 0.2}, "a2c": {0: 0.3}}
    finals["td3"] = {0: 0.5, 1: math.nan}  # a run whose validations.csv has no mean_score
    numbers = seed_statistics.compute(finals, reps=REPS)
    assert list(numbers["algorithms"]) == ["ppo", "sac"]
    assert "1 training seed" in numbers["left_out"]["a2c"]
    assert "mean_score" in numbers["left_out"]["td3"] and "seed 1" in numbers["left_out"]["td3"]
    sac = numbers["algorithms"]["sac"]
    assert sac["seeds"] == [0, 2] and sac["final_scores"] == [0.2, 0.7]
    for algo in ("ppo", "sac"):
        matrix = np.array([[finals[algo][s]] for s in sorted(finals[algo])])
        points, intervals = _direct_aggregates(matrix, REPS)
        for k, figure in enumerate(rliable_stats.AGGREGATES):
            row = numbers["algorithms"][algo][figure]
            assert (row["value"], row["low"], row["high"]) == (
                points[k],
                intervals[0, k],
                intervals[1, k],
            )
    (pair,) = numbers["probability_of_improvement"]
    point, band = _direct_improvement(
        np.array([[0.41], [0.62], [0.55]]), np.array([[0.2], [0.7]]), REPS
    )
    assert (pair["x"], pair["y"]) == ("ppo", "sac")
    assert (pair["value"], pair["low"], pair["high"]) == (point, band[0], band[1])
    assert pair["value"] == pytest.approx(3 / 6)  # 0.41, 0.62, 0.55 each beat 0.2, not 0.7
    page = "\n".join(seed_statistics.markdown_lines(numbers))
    assert "unit of replication is the training seed" in page and "| PPO | SAC |" in page
    assert "Left out: A2C: 1 training seed" in page


def test_an_old_validations_file_without_mean_score_is_read_and_extended(tmp_path):
    from capture_bench.training.common.policy_export import VALIDATIONS_FILE, append_validation
    from capture_bench.training.curves.command import SCORE, final_scores, read_curve

    run = tmp_path / "paper-ppo-0"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"hyperparameters": {"eval_episodes": 3}}))
    old = "step,wall_time_s,capture_rate,median_ratio_to_limit\r\n64,1.5,0.5,2.0\r\n"
    (run / VALIDATIONS_FILE).write_text(old)
    curve = read_curve(run, "ppo", 0)
    assert curve.values["capture_rate"].tolist() == [0.5] and math.isnan(curve.values[SCORE][0])
    assert math.isnan(final_scores({"ppo": [curve]})["ppo"][0])

    stats = {"capture_rate": 1.0, "median_ratio_to_limit": 1.5, SCORE: 0.6}
    append_validation(run, 128, 3.0, stats)  # a resumed run validated by this code
    with open(run / VALIDATIONS_FILE, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["step"] for r in rows] == ["64", "128"]
    assert rows[0][SCORE] == "" and rows[1][SCORE] == "0.6" and rows[1]["capture_rate"] == "1.0"
    curve = read_curve(run, "ppo", 0)
    assert final_scores({"ppo": [curve]}) == {"ppo": {0: 0.6}}


def test_the_profile_figure_depends_on_the_records_alone():
    from capture_bench.evaluation.reporting.report import figures

    data = _data(_equal_counts())
    first = figures(data, [rliable_report.FIGURE])
    np.random.seed(123)  # noqa: NPY002  (whatever the global state, the same bytes)
    assert figures(data, [rliable_report.FIGURE]) == first


def test_without_rliable_the_commands_that_need_it_say_so_in_one_line(
    tmp_path, capsys, monkeypatch
):
    import sys

    from capture_bench.evaluation.cli import main as evaluate
    from capture_bench.training.curves.command import main as curves

    monkeypatch.setitem(sys.modules, "rliable", None)  # import rliable now fails
    with pytest.raises(rliable_stats.RliableMissing, match="pip install rliable"):
        rliable_stats.require()
    monkeypatch.setattr(rliable_stats, "installed", lambda: False)
    assert evaluate(["--suite", "quick", "--workers", "1", "--out", str(tmp_path / "reports")]) == 2
    assert curves(["--out", str(tmp_path / "curves")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2 and all("pip install rliable" in line for line in lines), lines
    assert not (tmp_path / "reports").exists() and not (tmp_path / "curves").exists()
