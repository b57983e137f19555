"""Leaderboard statistics, checked on synthetic episode records against independent references.

Aggregation is a pure function of the records, so synthetic records are a fair test here; the
end-to-end runs on the real environment are in ``test_evaluate_cli.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from capture_bench.evaluation.reporting.aggregate import (
    Summary,
    failure_reasons,
    rank_agents,
    summarise_all,
    summary_row,
)
from capture_bench.evaluation.reporting.metrics import (
    Estimate,
    bootstrap_estimate,
    interquartile_mean,
    kaplan_meier,
    paired_comparison,
    wilson_interval,
)
from capture_bench.evaluation.running.rollout import EpisodeRecord

NAN = math.nan


def record(
    agent: str, seed: int, time: float | None, failure: str = "timeout", **kw
) -> EpisodeRecord:
    """A synthetic episode: captured at ``time`` s, or failed with ``failure`` at 10 s."""
    captured = time is not None
    values = dict(
        agent=agent,
        scenario=kw.pop("scenario", "paper"),
        seed=seed,
        outcome="captured" if captured else "failed",
        failure="" if captured else failure,
        capture_time=time if captured else NAN,
        end_time=time if captured else kw.pop("end_time", 10.0),
        physical_limit_time=1.0,
        ratio=time / 1.0 if captured else NAN,
        capture_time_estimated=NAN,
        distance_at_capture=5e-4 if captured else NAN,
        relative_speed_at_capture=0.01 if captured else NAN,
        position_rmse=0.002,
        velocity_rmse=0.003,
        mean_nees=6.0,
        path_length=0.4,
        saturated_share=0.5,
        steps=40,
        wall_clock_s=0.01,
    )
    values.update(kw)
    return EpisodeRecord(**values)


def test_wilson_matches_the_closed_form_reference_values():
    # Reference: Wilson (1927); 8/10 -> [0.4902, 0.9433] (e.g. statsmodels proportion_confint).
    est = wilson_interval(8, 10)
    assert est.value == pytest.approx(0.8)
    assert (est.low, est.high) == pytest.approx((0.4902, 0.9433), abs=1e-4)
    assert wilson_interval(0, 20).low == 0.0 and wilson_interval(20, 20).high == 1.0
    assert math.isnan(wilson_interval(0, 0).value)


def test_iqm_is_the_mean_of_the_middle_half():
    x = np.arange(1.0, 9.0)  # 1..8, middle half 3..6
    assert interquartile_mean(x) == pytest.approx(4.5)


def test_bootstrap_is_seeded_contains_its_estimate_and_handles_degenerate_data():
    rng = np.random.default_rng(0)
    x = rng.exponential(2.0, 60)
    a, b = bootstrap_estimate(x, "median"), bootstrap_estimate(x, "median")
    assert a == b  # fixed seed: identical intervals run to run
    assert a.value == pytest.approx(np.median(x)) and a.low < a.value < a.high
    assert bootstrap_estimate(x, "iqm").contains_value()
    assert math.isnan(bootstrap_estimate([], "mean").value)
    one = bootstrap_estimate([3.0, NAN], "mean")  # NaN dropped, one value: no interval
    assert one.value == 3.0 and math.isnan(one.low)
    assert bootstrap_estimate([2.0, 2.0, 2.0], "median") == Estimate(2.0, 2.0, 2.0)


def test_kaplan_meier_matches_a_hand_computed_curve():
    # events at 1, 2, 3; censored at 2.5 and 4. S: 1 -> 4/5 -> 3/5 -> (censor) -> 3/5*1/2 = 0.3
    curve = kaplan_meier([1.0, 2.0, 3.0, 2.5, 4.0], [True, True, True, False, False])
    at = dict(zip(curve.time.tolist(), curve.survival.tolist()))
    assert at[0.0] == 1.0
    assert at[1.0] == pytest.approx(0.8) and at[2.0] == pytest.approx(0.6)
    assert at[3.0] == pytest.approx(0.3)
    assert np.all(curve.low <= curve.survival + 1e-12) and np.all(
        curve.survival <= curve.high + 1e-12
    )
    median = curve.median()
    assert median.value == 3.0 and median.contains_value()


def test_kaplan_meier_without_any_capture_never_reaches_one_half():
    curve = kaplan_meier([10.0, 4.0], [False, False])
    assert np.all(curve.survival == 1.0) and curve.median().value == math.inf


def test_paired_comparison_counts_failures_as_worse_and_ties_as_half():
    agent = {1: 1.0, 2: 2.0, 3: math.inf, 4: 3.0, 5: math.inf}
    ref = {1: 2.0, 2: 2.0, 3: 1.0, 4: math.inf, 5: math.inf, 6: 1.0}  # seed 6 unpaired
    cmp = paired_comparison(agent, ref)
    assert cmp.pairs == 5
    # seeds: 1 better, 2 tie, 3 worse, 4 better (ref failed), 5 tie (both failed)
    assert cmp.prob_improvement.value == pytest.approx((1 + 0.5 + 0 + 1 + 0.5) / 5)
    assert (cmp.both_captured, cmp.only_agent, cmp.only_reference, cmp.neither) == (2, 1, 1, 1)
    assert cmp.time_difference.value == pytest.approx(np.median([1.0 - 2.0, 0.0]))
    assert cmp.prob_improvement.contains_value() and cmp.time_difference.contains_value()


def _cells() -> list[EpisodeRecord]:
    recs = []
    for seed in range(12):
        recs.append(record("incremental_ik", seed, 2.0 + 0.1 * seed))
        fast = None if seed % 4 == 0 else 1.5 + 0.1 * seed
        recs.append(record("fast", seed, fast, failure="collision", end_time=0.7))
        recs.append(record("oracle", seed, 1.0))
        recs.append(record("hold", seed, None))
    return recs


def test_summaries_are_consistent_with_their_records():
    recs = _cells()
    summaries = {s.agent: s for s in summarise_all(recs)}
    fast = summaries["fast"]
    assert (fast.episodes, fast.captured) == (12, 9)
    assert fast.failures == {"collision": 3}
    captured_times = [r.capture_time for r in recs if r.agent == "fast" and r.captured]
    assert fast.figures["capture_time_median"].value == pytest.approx(np.median(captured_times))
    assert fast.paired is not None and fast.paired.pairs == 12
    assert summaries["incremental_ik"].paired is None  # the reference is not compared with itself
    for s in summaries.values():
        for est in [s.capture_rate, s.km_median, *s.figures.values()]:
            assert est.contains_value()
    assert math.isnan(summaries["hold"].figures["capture_time_median"].value)
    assert summaries["hold"].km_median.value == math.inf


def test_summary_row_has_fixed_columns_and_all_failure_reasons():
    summaries = summarise_all(_cells())
    reasons = failure_reasons(summaries)
    assert reasons[:4] == ["timeout", "collision", "target_lost", "unreachable"]
    rows = [summary_row(s, reasons) for s in summaries]
    assert len({tuple(r) for r in rows}) == 1  # same columns in every row
    hold = next(r for r in rows if r["agent"] == "hold")
    assert hold["failures_timeout"] == 12 and hold["capture_rate"] == 0.0


def test_ranking_follows_its_rule_and_leaves_privileged_agents_unranked():
    ranking = rank_agents(summarise_all(_cells()))
    order = [(r.agent, r.rank) for r in ranking]
    # incremental_ik 12/12 > fast 9/12 > hold 0/12; the oracle is listed last, unranked
    assert order == [("incremental_ik", 1), ("fast", 2), ("hold", 3), ("oracle", None)]


def test_ranking_ties_on_capture_rate_are_broken_by_the_ratio():
    recs = [record("slow", s, 3.0) for s in range(5)] + [record("quick", s, 1.5) for s in range(5)]
    ranking = rank_agents(summarise_all(recs, reference_agent="slow"))
    assert [r.agent for r in ranking] == ["quick", "slow"]


def test_the_overall_table_shows_the_median_relative_speed_at_capture():
    """Mean over scenarios (with a capture) of the median relative speed at capture: a column of
    the ranking table in every output, not part of the ranking."""
    from capture_bench.evaluation.reporting.report import RANKING_HEADER, markdown, ranking_cells

    recs = [record("slow", s, 3.0) for s in range(5)]  # 10 mm/s on paper
    recs += [
        record("slow", s, 3.0, scenario="drift", relative_speed_at_capture=0.05 + 0.01 * s)
        for s in range(3)
    ]  # fmt: skip  (median 60 mm/s on drift)
    recs += [record("quick", s, 1.5, relative_speed_at_capture=0.2) for s in range(5)]
    recs += [record("quick", s, None, scenario="drift") for s in range(3)]  # no capture there
    ranking = rank_agents(summarise_all(recs, reference_agent="slow"))
    assert [r.agent for r in ranking] == ["slow", "quick"]  # by capture rate, not by speed
    assert [r.mean_relative_speed_median for r in ranking] == pytest.approx([0.035, 0.2])
    speed = RANKING_HEADER.index("mean median rel. speed at capture, mm/s")
    assert all(len(ranking_cells(r)) == len(RANKING_HEADER) for r in ranking)
    assert [ranking_cells(r)[speed] for r in ranking] == ["35", "200"]
    nowhere = rank_agents(summarise_all([record("hold", s, None) for s in range(3)]))
    assert math.isnan(nowhere[0].mean_relative_speed_median)
    assert ranking_cells(nowhere[0])[speed] == "—"
    data = _report_data()
    header = "| " + " | ".join(RANKING_HEADER) + " |"
    assert header in markdown(data).splitlines()


def test_summarise_refuses_an_empty_cell():
    from capture_bench.evaluation.reporting.aggregate import summarise

    with pytest.raises(ValueError):
        summarise([])
    assert isinstance(summarise([record("a", 0, 1.0)]), Summary)


def _report_data(suite: str = "synthetic"):
    from capture_bench.evaluation.reporting.report import ReportData

    recs = _cells() + [record("fast", s, 1.2, scenario="drift") for s in range(3)]
    recs += [record("incremental_ik", s, None, scenario="drift") for s in range(3)]
    summaries = summarise_all(recs)
    return ReportData(
        suite=suite,
        description="synthetic records",
        command="python evaluate.py --suite synthetic",
        reference="incremental_ik",
        records=recs,
        summaries=summaries,
        ranking=rank_agents(summaries),
        provenance={"seeds": {"paper": list(range(12))}, "timing": {"wall_clock_s": math.inf}},
    )


def test_report_files_from_records(tmp_path):
    import csv
    import json
    from html.parser import HTMLParser

    from capture_bench.evaluation.reporting.report import write_report

    target = write_report(_report_data(), tmp_path)
    assert target == tmp_path / "synthetic"
    names = {p.name for p in target.iterdir()}
    assert {
        "leaderboard.md",
        "leaderboard.html",
        "results.csv",
        "episodes.csv",
        "results.json",
        "survival_paper.png",
        "survival_drift.png",
        "failures_by_reason.png",
        "ratio_to_limit.png",
    } <= names
    assert [p.name for p in tmp_path.iterdir()] == ["synthetic"]  # no staging directory left
    md = (target / "leaderboard.md").read_text()
    assert "python evaluate.py --suite synthetic" in md.splitlines()[:12]
    rows = list(csv.DictReader(open(target / "results.csv")))
    assert len(rows) == 6 and len(list(csv.DictReader(open(target / "episodes.csv")))) == 54
    payload = json.loads((target / "results.json").read_text())  # strict JSON: no NaN
    assert payload["provenance"]["timing"]["wall_clock_s"] == "inf"

    class Images(HTMLParser):
        sources: list[str] = []

        def handle_starttag(self, tag, attrs):
            if tag == "img":
                self.sources.append(dict(attrs)["src"])

    parser = Images()
    parser.feed((target / "leaderboard.html").read_text())
    assert len(parser.sources) == 7  # 3 summary figures, 2 survival, failures, ratio
    assert all(s.startswith("data:image/png;base64,iVBOR") for s in parser.sources)


def test_a_failed_report_leaves_the_previous_one_and_no_staging_directory(tmp_path, monkeypatch):
    from capture_bench.evaluation.reporting import plots
    from capture_bench.evaluation.reporting.report import write_report

    write_report(_report_data(), tmp_path)
    before = (tmp_path / "synthetic" / "results.csv").read_bytes()

    def broken(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(plots, "ratio_figure", broken)
    with pytest.raises(RuntimeError):
        write_report(_report_data(), tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ["synthetic"]
    assert (tmp_path / "synthetic" / "results.csv").read_bytes() == before
    with pytest.raises(RuntimeError):
        write_report(_report_data("fresh"), tmp_path)
    assert not (tmp_path / "fresh").exists()


def test_figure_groups_split_every_figure_once_and_an_unknown_name_is_refused():
    from capture_bench.evaluation.reporting.report import figure_groups, figure_names, figures

    data = _report_data()
    names = figure_names(data)
    for groups in (1, 2, 4, 50):
        split = figure_groups(data, groups)
        assert sorted(n for group in split for n in group) == sorted(names)
        assert 1 <= len(split) <= min(groups, len(names)) and all(split)
    assert figure_groups(data, 4)[0][0] == "ratio_to_limit.png"  # the costliest leads
    with pytest.raises(ValueError, match="no figure named 'nope.png'"):
        figures(data, ["nope.png"])


def test_summaries_made_in_a_pool_are_those_made_in_one_process():
    """The evaluation summarises its cells in worker processes (each cell's bootstrap has its
    own fixed seed): the same summaries, in the same order, as summarise_all."""
    from dataclasses import replace

    from capture_bench.evaluation.pipeline import summarise_in_pool

    recs = _cells() + [replace(r, scenario="drift") for r in _cells()[5:]]
    alone = summarise_all(recs)
    pooled = summarise_in_pool(recs, "incremental_ik", workers=2)
    reasons = failure_reasons(alone)
    rows = [repr(summary_row(s, reasons)) for s in pooled]  # NaN cells: equal as text
    assert rows == [repr(summary_row(s, reasons)) for s in alone]
    assert repr([s.paired for s in pooled]) == repr([s.paired for s in alone])
