"""The report's summary (issue 15 point 1): its numbers equal the tables' (ranking, intervals,
heatmap cells), the probability of improvement is rliable's definition (checked by brute force),
and every summary plot is written and embedded in the one-file HTML."""

from __future__ import annotations

import base64
import math

import numpy as np
import pytest

from capture_bench.evaluation.reporting.report import SUMMARY_FIGURES, summary_text
from capture_bench.evaluation.reporting.summary import (
    heatmap_cells,
    probability_of_improvement,
    ranking_intervals,
    score,
)

AGENTS = "incremental_ik,pure_pursuit,intercept,hold"


@pytest.fixture(scope="module")
def report(tmp_path_factory, evaluated):
    """4 agents x 2 scenarios x 6 seeds, serial; the ReportData and the report folder."""
    argv = ["--agents", AGENTS, "--scenarios", "paper,tumbling", "--episodes", "6"]
    return evaluated([*argv, "--workers", "1"], tmp_path_factory.mktemp("summary"))


def test_the_ranking_plot_has_the_rankings_numbers_and_intervals_around_them(report):
    data, _ = report
    rows = ranking_intervals(data.records, data.ranking)
    ranked = [r for r in data.ranking if not r.privileged]
    assert [r.agent for r in rows] == [r.agent for r in ranked]
    for row, line in zip(rows, ranked):
        assert row.mean_capture_rate == pytest.approx(line.mean_capture_rate, abs=1e-12)
        assert row.low <= row.mean_capture_rate <= row.high
    assert rows[0].tied_with_previous is None
    assert rows[-1].agent == "hold" and rows[-1].high == 0.0  # hold never captures
    assert rows[-1].tied_with_previous is False  # 0 against a captured share: distinguishable


def test_the_heatmap_cells_are_the_tables(report):
    data, _ = report
    agents = [r.agent for r in data.ranking]
    scenarios = ["paper", "tumbling"]
    rate, ratio = heatmap_cells(data.summaries, agents, scenarios)
    for s in data.summaries:
        i, j = agents.index(s.agent), scenarios.index(s.scenario)
        assert rate[i, j] == s.capture_rate.value
        want = s.figures["ratio_median"].value
        assert ratio[i, j] == want or (math.isnan(ratio[i, j]) and math.isnan(want))


def test_probability_of_improvement_is_rliables_definition_by_brute_force(report):
    data, _ = report
    agents = [r.agent for r in data.ranking]
    matrix = probability_of_improvement(data.records, agents)
    for i, a in enumerate(agents):
        for j, b in enumerate(agents):
            if i == j:
                assert matrix[i, j] == 0.5
                continue
            per = []
            for scenario in ("paper", "tumbling"):
                x = [score(r) for r in data.records if r.agent == a and r.scenario == scenario]
                y = [score(r) for r in data.records if r.agent == b and r.scenario == scenario]
                per.append(np.mean([(u > v) + 0.5 * (u == v) for u in x for v in y]))
            assert matrix[i, j] == pytest.approx(np.mean(per), abs=1e-12)
            assert matrix[i, j] + matrix[j, i] == pytest.approx(1.0, abs=1e-12)


def test_every_summary_plot_is_written_and_embedded_before_the_scenarios(report):
    data, folder = report
    html = (folder / "leaderboard.html").read_text()
    md = (folder / "leaderboard.md").read_text()
    positions = {}
    for name in SUMMARY_FIGURES:
        png = (folder / name).read_bytes()
        assert png.startswith(b"\x89PNG")
        encoded = base64.b64encode(png).decode("ascii")
        assert encoded in html
        positions[name] = html.index(encoded)
        assert f"]({name})" in md  # ![what it shows](file)
    # the ranking's figure under its table, the others next; all before the per-scenario tables
    assert html.index("<h2>Overall ranking</h2>") < positions["summary_ranking.png"]
    assert max(positions.values()) < html.index('<section id="scenarios">')
    assert summary_text(data) in html and 'src="http' not in html


def test_the_u_statistic_is_scipys_exactly():
    from scipy.stats import mannwhitneyu

    from capture_bench.evaluation.reporting.summary import mann_whitney_u

    rng = np.random.default_rng(3)
    for _ in range(50):
        x = np.round(rng.uniform(0, 1, rng.integers(1, 120)), 1) * (rng.uniform(size=1) > 0.2)
        y = np.round(rng.uniform(0, 1, rng.integers(1, 120)), 1)  # ties, zeros (failures)
        assert mann_whitney_u(x, y) == mannwhitneyu(x, y, alternative="two-sided").statistic
