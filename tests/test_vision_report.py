"""The report's rendered-vs-analytic section, on synthetic records: which scenarios pair, the paired
figures against independent references, and where the section appears (and where it does not)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from test_evaluation_metrics import _report_data, record

from capture_bench.evaluation.reporting.aggregate import rank_agents, summarise_all
from capture_bench.evaluation.reporting.report import (
    ReportData,
    figure_names,
    html_page,
    markdown,
    write_report,
)
from capture_bench.evaluation.reporting.vision import (
    HEADER,
    TEXT,
    TITLE,
    left_out_text,
    rendered_twins,
    vision_comparisons,
)
from capture_bench.evaluation.running.suites import load_suite

ROOT = Path(__file__).resolve().parents[1]
LOST = (3, 7, 11, 15, 19)  # seeds the rendered camera loses


def _paired(agent: str = "incremental_ik", seeds: int = 20) -> list:
    """``agent`` captures every seed on paper; on paper_rendered it misses `LOST` and is
    slower by 0.5 + 0.01 * seed s (ratio = time: the synthetic bound is 1 s)."""
    recs = []
    for seed in range(seeds):
        time = 2.0 + 0.05 * seed
        recs.append(record(agent, seed, time, scenario="paper"))
        slower = None if seed in LOST else time + 0.5 + 0.01 * seed
        recs.append(record(agent, seed, slower, scenario="paper_rendered"))
    return recs


def _data(recs: list, suite: str = "vision", models: dict | None = None) -> ReportData:
    """A report of ``recs``, ``models`` the provenance's trained models (label -> entry)."""
    summaries = summarise_all(recs)
    provenance: dict = {"seeds": {}}
    if models is not None:
        provenance["config_hashes"] = {"models": models}
    return ReportData(
        suite=f"{suite}-synthetic",
        description="synthetic records",
        command=f"python evaluate.py --suite {suite}",
        reference="incremental_ik",
        records=recs,
        summaries=summaries,
        ranking=rank_agents(summaries),
        provenance=provenance,
    )


def _images(data: ReportData) -> dict[str, bytes]:
    """Stand-in figures: the section is text, drawing the real ones would only cost time."""
    return {name: b"\x89PNG" for name in figure_names(data)}


def _scenario(mode: str, seeds: list[int]) -> SimpleNamespace:
    return SimpleNamespace(camera=SimpleNamespace(mode=mode), evaluation_seeds=seeds)


def test_twins_are_the_shipped_rendered_scenarios_with_the_same_seeds():
    names = ["grasp_rendered", "paper", "drift", "paper_rendered", "grasp"]
    assert rendered_twins(names) == [("paper", "paper_rendered"), ("grasp", "grasp_rendered")]
    assert rendered_twins(["paper", "drift", "grasp_rendered"]) == []  # no twin evaluated
    assert rendered_twins(["mine", "mine_rendered"]) == []  # not shipped: nothing to check

    fakes = {
        "a": _scenario("analytic", [1, 2]),
        "a_rendered": _scenario("rendered", [1, 3]),  # other seeds: other targets
        "b": _scenario("analytic", [1, 2]),
        "b_rendered": _scenario("analytic", [1, 2]),  # not the rendered camera
        "c": _scenario("analytic", [5, 6]),
        "c_rendered": _scenario("rendered", [5, 6]),
    }
    assert rendered_twins(list(fakes), load=fakes.__getitem__) == [("c", "c_rendered")]


def test_the_paired_difference_and_its_interval_are_right():
    (c,) = vision_comparisons(_paired())
    assert (c.subject, c.a, c.b, c.seeds) == (
        "incremental_ik",
        "paper",
        "paper_rendered",
        20,
    )
    assert (c.captured_a, c.captured_b) == (20, 15)
    assert (c.only_a, c.only_b, c.both_captured) == (5, 0, 15)
    assert c.capture_rate_a.value == 1.0 and c.capture_rate_b.value == 0.75
    # Wilson (1927) for 15/20: [0.5313, 0.8881]
    rate = c.capture_rate_b
    assert (rate.low, rate.high) == pytest.approx((0.5313, 0.8881), abs=1e-4)

    diff = c.capture_rate_difference
    assert diff.value == pytest.approx(-0.25)
    # independent percentile bootstrap of the per-seed differences (0 or -1) over seeds
    per_seed = -np.isin(np.arange(20), LOST).astype(float)
    rng = np.random.default_rng(1)
    means = per_seed[rng.integers(0, 20, (20000, 20))].mean(axis=1)
    low, high = np.percentile(means, [2.5, 97.5])
    assert (diff.low, diff.high) == pytest.approx((low, high), abs=0.051)  # steps of 1/20
    assert diff.low < -0.25 < diff.high < 0.0  # the seeds tell the cameras apart

    both = [s for s in range(20) if s not in LOST]
    assert c.ratio_median_a.value == pytest.approx(np.median(2.0 + 0.05 * np.arange(20)))
    rendered = [2.0 + 0.05 * s + 0.5 + 0.01 * s for s in both]
    assert c.ratio_median_b.value == pytest.approx(np.median(rendered))
    assert c.ratio_difference.value == pytest.approx(np.median([0.5 + 0.01 * s for s in both]))
    for est in (c.ratio_median_a, c.ratio_median_b, c.ratio_difference):
        assert est.low <= est.value <= est.high and est.low < est.high


def test_seeds_in_one_scenario_of_the_pair_only_are_left_out_and_named():
    recs = [r for r in _paired(seeds=10) if not (r.scenario == "paper_rendered" and r.seed >= 8)]
    recs.append(record("incremental_ik", 42, 2.0, scenario="paper_rendered"))
    (c,) = vision_comparisons(recs)
    assert c.seeds == 8 and c.unpaired_a == (8, 9) and c.unpaired_b == (42,)
    assert (c.captured_a, c.captured_b) == (8, 6)  # seeds 3 and 7 lost
    assert c.capture_rate_difference.value == pytest.approx(-2 / 8)
    text = left_out_text([c])
    assert "incremental_ik: 2 seeds of paper only (8, 9)" in text
    assert "1 seed of paper_rendered only (42)" in text
    md = markdown(_data(recs))
    assert text in md
    assert left_out_text(vision_comparisons(_paired())) == ""


def test_no_twin_or_no_common_seed_gives_no_comparison():
    drift = [record("incremental_ik", s, 1.0, scenario="drift") for s in range(5)]
    only_analytic = [r for r in _paired() if r.scenario == "paper"]
    assert vision_comparisons(only_analytic + drift) == []
    # pure_pursuit ran both scenarios but on different seeds: no row for it
    apart = [record("pure_pursuit", s, 1.0, scenario="paper") for s in range(3)]
    apart += [record("pure_pursuit", s, 1.0, scenario="paper_rendered") for s in range(3, 6)]
    assert [c.subject for c in vision_comparisons(_paired() + apart)] == ["incremental_ik"]
    assert vision_comparisons(apart) == []
    assert TITLE not in markdown(_data(apart + drift))


def test_the_markdown_html_and_json_hold_the_section(tmp_path):
    recs = _paired() + _paired("pure_pursuit")
    data = _data(recs)
    md = markdown(data)
    lines = md.splitlines()
    assert f"## {TITLE}" in lines and TEXT in lines and "### paper vs paper_rendered" in lines
    header = "| " + " | ".join(HEADER) + " |"
    start = lines.index(header)
    rows = lines[start + 2 : start + 4]
    assert rows[0].startswith("| incremental_ik (reference) | 20 | 20/20 = 1.00 [")
    assert rows[1].startswith("| pure_pursuit | 20 | ")
    assert "| 15/20 = 0.75 [0.53, 0.89] | -0.25 [" in rows[0] and "| 5 / 0 / 15 |" in rows[0]
    assert lines.index(f"## {TITLE}") > lines.index("## paper_rendered")  # after the scenarios

    page = html_page(data, _images(data))
    assert f"<h2>{TITLE}</h2>" in page and "<h3>paper vs paper_rendered</h3>" in page
    assert "<th>Δ capture rate</th>" in page and "<td>5 / 0 / 15</td>" in page

    target = write_report(data, tmp_path, images=_images(data))
    payload = json.loads((target / "results.json").read_text())
    assert [(v["agent"], v["analytic"], v["rendered"]) for v in payload["vision"]] == [
        ("incremental_ik", "paper", "paper_rendered"),
        ("pure_pursuit", "paper", "paper_rendered"),
    ]
    row = payload["vision"][0]
    assert row["seeds"] == 20 and row["capture_rate_difference"] == pytest.approx(-0.25)
    assert row["capture_rate_difference_low"] < -0.25 < row["capture_rate_difference_high"]
    assert row["unpaired_analytic"] == [] and row["only_analytic"] == 5
    assert (target / "leaderboard.md").read_text() == md


def test_a_report_without_rendered_scenarios_has_no_section(tmp_path):
    data = _report_data()
    assert vision_comparisons(data.records) == []
    md = markdown(data)
    assert TITLE not in md and " | ".join(HEADER) not in md
    assert TITLE not in html_page(data, _images(data))
    target = write_report(data, tmp_path, images=_images(data))
    payload = json.loads((target / "results.json").read_text())
    assert set(payload) == {
        "suite",
        "command",
        "reference",
        "ranking_rule",
        "ranking",
        "results",
        "provenance",
        "rliable",  # every report has it (tests/test_rliable_stats.py)
    }


def test_the_vision_suite_pairs_each_scenario_with_its_rendered_twin():
    suite = load_suite("vision")
    assert suite.scenarios == ("paper", "paper_rendered", "grasp", "grasp_rendered")
    assert rendered_twins(suite.scenarios) == [
        ("paper", "paper_rendered"),
        ("grasp", "grasp_rendered"),
    ]
    assert suite.episodes == 50 and suite.reference == "incremental_ik" and suite.videos
    models = [a for a in suite.agents if a.startswith("models/")]
    assert models == ["models/dagger-dls-paper", "models/dagger-dls-all"]
    assert all((ROOT / m / "metadata.json").is_file() for m in models)
