"""The report's pixels-vs-estimate section, on synthetic records: which agents pair, the paired
figures (those of `capture_bench.evaluation.reporting.paired.compare`, checked against independent
references in ``test_vision_report.py``), and where the section appears."""

from __future__ import annotations

import json

import pytest
from test_evaluation_metrics import record
from test_vision_report import _data as _vision_data
from test_vision_report import _images

from capture_bench.evaluation.reporting.pixel_comparison import (
    HEADER,
    TEXT,
    TITLE,
    pixel_comparisons,
)
from capture_bench.evaluation.reporting.report import ReportData, html_page, markdown, write_report

MODELS = {
    "ppo-paper": {"trained_observation_source": "ekf"},
    "pixels-paper (pixels)": {"trained_observation_source": "pixels"},
}
LOST = (1, 4, 9)  # seeds the pixel policy loses


def _records(seeds: int = 12) -> list:
    recs = []
    for seed in range(seeds):
        for scenario in ("paper", "grasp"):
            recs.append(record("incremental_ik", seed, 2.0 + 0.1 * seed, scenario=scenario))
            recs.append(record("ppo-paper", seed, 1.5 + 0.1 * seed, scenario=scenario))
            recs.append(record("pure_pursuit", seed, 3.0, scenario=scenario))
            pixel = None if seed in LOST else 2.5 + 0.1 * seed
            recs.append(record("pixels-paper (pixels)", seed, pixel, scenario=scenario))
    return recs


def _data(recs: list, models: dict) -> ReportData:
    return _vision_data(recs, "pixels", models)


def test_each_pixel_model_pairs_with_the_reference_and_the_estimate_fed_models():
    comparisons = pixel_comparisons(_records(), "incremental_ik", MODELS)
    pairs = [(c.subject, c.a, c.b) for c in comparisons]
    assert pairs == [
        ("paper", "incremental_ik", "pixels-paper (pixels)"),
        ("paper", "ppo-paper", "pixels-paper (pixels)"),
        ("grasp", "incremental_ik", "pixels-paper (pixels)"),
        ("grasp", "ppo-paper", "pixels-paper (pixels)"),
    ]  # pure_pursuit is a built-in other than the reference: not paired
    c = comparisons[1]
    assert (c.seeds, c.captured_a, c.captured_b, c.only_a, c.only_b) == (12, 12, 9, 3, 0)
    assert c.capture_rate_difference.value == pytest.approx(-3 / 12)
    assert c.ratio_difference.value == pytest.approx(1.0)  # 2.5 + 0.1 s - (1.5 + 0.1 s)


def test_the_markdown_html_and_json_hold_the_section(tmp_path):
    data = _data(_records(), MODELS)
    md = markdown(data)
    lines = md.splitlines()
    assert f"## {TITLE}" in lines and TEXT in lines and "### paper: pixels-paper (pixels)" in lines
    start = lines.index("| " + " | ".join(HEADER) + " |")
    assert lines[start + 2].startswith("| incremental_ik (reference) | 12 | 12/12 = 1.00 [")
    assert lines[start + 3].startswith("| ppo-paper | 12 | 12/12 = 1.00 [")
    assert "| 3 / 0 / 9 |" in lines[start + 3]
    assert f"<h2>{TITLE}</h2>" in html_page(data, _images(data))
    target = write_report(data, tmp_path, images=_images(data))
    payload = json.loads((target / "results.json").read_text())
    row = payload["pixels"][1]
    assert (row["scenario"], row["estimate_agent"], row["pixel_agent"]) == (
        "paper", "ppo-paper", "pixels-paper (pixels)",
    )  # fmt: skip
    assert row["captured_estimate_agent"] == 12 and row["captured_pixel_agent"] == 9
    assert row["capture_rate_difference"] == pytest.approx(-0.25)


def test_a_report_without_a_pixel_model_has_no_section():
    models = {"ppo-paper": MODELS["ppo-paper"]}
    recs = [r for r in _records() if "pixels" not in r.agent]
    assert pixel_comparisons(recs, "incremental_ik", models) == []
    assert TITLE not in markdown(_data(recs, models))
