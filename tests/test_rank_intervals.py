"""The ranking's rank intervals and tie groups (a paired bootstrap over seeds within scenarios),
the scenarios left out of the ranking (``ranked: false``), and the report's first line, the
capture rule. Synthetic records: the ranking is a pure function of them."""

from __future__ import annotations

import dataclasses
import html
import json
import math
import random

import numpy as np
import pytest

from capture_bench.evaluation.reporting.aggregate import (
    RankingRow,
    Summary,
    counted_scenarios,
    rank_agents,
    ranks_under_weights,
    seed_weights,
    summarise_all,
    tie_groups,
    unranked_scenarios,
    with_rank_intervals,
)
from capture_bench.evaluation.reporting.metrics import Estimate
from capture_bench.evaluation.reporting.report import (
    RANKING_HEADER,
    READING,
    ReportData,
    _sanitise,
    capture_rule,
    capture_rule_text,
    figures,
    html_page,
    markdown,
    ranking_cells,
    report_capture_rule,
    summary_text,
)
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.task.scenarios import ConfigError, Scenario, load_scenario
from tests.records import record


def agent_records(agent: str, scenario: str, seeds: range, caught, ratio=lambda s: 1.2):
    return [record(agent, scenario, s, ratio(s) if caught(s) else None) for s in seeds]


def ranked(records: list[EpisodeRecord], **kw) -> list[RankingRow]:
    return rank_agents(summarise_all(records, reference_agent="best"), records=records, **kw)


def interval(row: RankingRow) -> tuple:
    return (row.rank_low, row.rank_high)


@pytest.fixture(scope="module")
def plain():
    """``best`` captures every episode; ``twin_a`` and ``twin_b`` are the same episodes (80%);
    ``weak`` half; 40 seeds on each of two scenarios."""
    seeds = range(40)
    records = []
    for scenario in ("s1", "s2"):
        records += agent_records("best", scenario, seeds, lambda s: True, lambda s: 1.1)
        for twin in ("twin_a", "twin_b"):
            records += agent_records(
                twin, scenario, seeds, lambda s: s % 5, lambda s: 1.3 + s / 100
            )
        records += agent_records("weak", scenario, seeds, lambda s: s % 2 == 0)
    return records


def test_a_clearly_better_agent_ranks_1_to_1_and_identical_agents_are_tied(plain):
    rows = {r.agent: r for r in ranked(plain)}
    assert [rows[a].rank for a in ("best", "twin_a", "twin_b", "weak")] == [1, 2, 3, 4]
    assert interval(rows["best"]) == (1, 1) and not rows["best"].tied
    # identical records: the name orders them, the resamples cannot: both span ranks 2-3
    assert interval(rows["twin_a"]) == interval(rows["twin_b"]) == (2, 3)
    assert (rows["twin_b"].tie_first, rows["twin_b"].tie_last) == (2, 3) and rows["twin_a"].tied
    assert interval(rows["weak"]) == (4, 4) and not rows["weak"].tied
    cells = {r.agent: dict(zip(RANKING_HEADER, ranking_cells(r))) for r in rows.values()}
    assert cells["twin_b"]["rank interval (95%)"] == "2–3"
    assert cells["twin_b"]["tie group"] == "ranks 2–3"
    assert (cells["best"]["rank interval (95%)"], cells["best"]["tie group"]) == ("1–1", "—")


def test_the_report_draws_the_ties_and_says_how_they_are_decided(plain):
    data = _data(plain, rank_agents(summarise_all(plain, reference_agent="best")))
    assert interval(data.ranking[1]) == (2, 3)  # the report computed the intervals itself
    text = summary_text(data)
    assert "ranks 2–3: twin_a, twin_b" in text and "best" not in text
    md = markdown(data, (None, "not needed"))
    assert "| 2 | twin_a | 0.800 | 2–3 | ranks 2–3 |" in md
    assert "overlaps that of the agent ranked just above it is tied with it" in md
    png = figures(data, ["summary_ranking.png"])["summary_ranking.png"]
    assert png.startswith(b"\x89PNG")


def test_rank_intervals_are_deterministic_whatever_the_order_of_the_records():
    rng = np.random.default_rng(7)
    records = []
    for scenario in ("s1", "s2", "s3"):
        for agent, rate in (("a", 0.8), ("b", 0.78), ("c", 0.75), ("d", 0.5)):
            caught = rng.uniform(size=30) < rate
            ratios = rng.uniform(1.0, 2.0, 30)
            records += [
                record(agent, scenario, s, ratios[s] if caught[s] else None) for s in range(30)
            ]
    first, again = ranked(records), ranked(records)
    assert first == again
    coarse = [with_rank_intervals(first, records, resamples=12) for _ in range(2)]
    assert coarse[0] == coarse[1]
    agents, scenarios = ["a", "b", "c", "d"], ["s1", "s2", "s3"]
    draws = [seed_weights(records, agents, scenarios, 50, 0)["s2"][1] for _ in range(2)]
    assert np.array_equal(*draws)
    shuffled = list(records)
    random.Random(1).shuffle(shuffled)
    ends = [(r.agent, *interval(r), r.tie_first, r.tie_last) for r in first]
    assert [(r.agent, *interval(r), r.tie_first, r.tie_last) for r in ranked(shuffled)] == ends
    assert any(r.rank_low != r.rank_high for r in first)  # the resamples do move the ranks


def test_each_resample_is_ranked_by_the_ranking_rule_itself():
    """The vectorised ranks of each resample against `rank_agents` on summaries made from
    the resampled episodes by ``np.median``: level agents (the same mean capture rate and mean
    median ratio) span the ranks the name spreads them over."""
    rng = np.random.default_rng(3)
    records = []
    for scenario in ("s1", "s2"):
        caught = rng.uniform(size=12) < 0.7
        ratios = {a: rng.uniform(1.0, 1.5, 12) for a in ("a", "c")}
        ratios["a_copy"] = ratios["a"]
        for agent in ("a", "a_copy", "c"):  # the same captures: the median ratio orders them
            records += [
                record(agent, scenario, s, ratios[agent][s] if caught[s] else None)
                for s in range(12)
            ]
        records += [record("b", scenario, s, 1.2 if s % 3 else None) for s in range(12)]
        records += [record("never", scenario, s, None) for s in range(12)]
    records += [record("part", "s1", s, 1.0) for s in range(6)]  # played half of s1, no s2
    agents = ["a", "a_copy", "c", "b", "never", "part"]
    weights = seed_weights(records, agents, ["s1", "s2"], 25, 11)
    best, worst = ranks_under_weights(records, agents, weights)
    for k in range(25):
        summaries = []
        for scenario, (seeds, w) in weights.items():
            for agent in agents:
                drawn = [
                    r
                    for r in records
                    if (r.agent, r.scenario) == (agent, scenario)
                    for _ in range(int(w[k, seeds.index(r.seed)]))
                ]
                if drawn:
                    summaries.append(_summary(agent, scenario, drawn))
        rows = rank_agents(summaries, privileged=(), unranked=())
        for row in rows:
            level = [
                o.rank
                for o in rows
                if round(o.mean_capture_rate, 9) == round(row.mean_capture_rate, 9)
                and o.mean_ratio_median == row.mean_ratio_median
            ]
            i = agents.index(row.agent)
            assert (best[k, i], worst[k, i]) == (min(level), max(level)), (k, row.agent)
    assert (best != worst).any() and (best == worst).any()


def _summary(agent: str, scenario: str, drawn: list[EpisodeRecord]) -> Summary:
    ratios = [r.ratio for r in drawn if r.captured and math.isfinite(r.ratio)]
    nan = Estimate(math.nan)
    return Summary(
        agent=agent,
        scenario=scenario,
        episodes=len(drawn),
        captured=sum(r.captured for r in drawn),
        capture_rate=Estimate(sum(r.captured for r in drawn) / len(drawn)),
        figures={
            "ratio_median": Estimate(float(np.median(ratios)) if ratios else math.nan),
            "relative_speed_at_capture_median": nan,
        },
        km_median=nan,
        survival=None,  # type: ignore[arg-type]
        failures={},
        paired=None,
        wall_clock_s_mean=0.0,
    )


def test_a_tie_group_chains_overlapping_neighbours():
    intervals = [(1, 2), (2, 3), (3, 3), (4, 5), (4, 5), (6, 6)]
    assert tie_groups(intervals) == [(1, 3), (1, 3), (1, 3), (4, 5), (4, 5), (6, 6)]
    assert tie_groups([(1, 1), (2, 2)]) == [(1, 1), (2, 2)] and tie_groups([]) == []


def test_privileged_agents_are_listed_unranked_and_leave_the_others_ranks_alone(plain):
    oracle = [record("oracle", r.scenario, r.seed, 1.0) for r in plain if r.agent == "best"]
    with_oracle = ranked(plain + oracle, privileged={"oracle"})
    assert with_oracle[-1].agent == "oracle" and with_oracle[-1].rank is None
    assert (with_oracle[-1].rank_low, with_oracle[-1].tie_first) == (None, None)
    assert with_oracle[:-1] == ranked(plain)
    assert ranking_cells(with_oracle[-1])[3:5] == ["—", "—"]


def test_an_unranked_scenario_changes_no_rank_and_has_its_own_table():
    seeds = range(30)
    records = []
    records += agent_records("steady", "s1", seeds, lambda s: True)  # 100% on s1
    records += agent_records("sweeper", "s1", seeds, lambda s: s % 3)  # 67% on s1
    records += agent_records("steady", "eq20", seeds, lambda s: s % 2)  # 50% on eq20
    records += agent_records("sweeper", "eq20", seeds, lambda s: True)  # 100% on eq20
    everything = ranked(records, unranked=())
    assert [r.agent for r in everything] == ["sweeper", "steady"]  # eq20 would decide
    rows = ranked(records, unranked={"eq20"})
    alone = ranked([r for r in records if r.scenario == "s1"])
    assert [(r.agent, interval(r)) for r in rows] == [("steady", (1, 1)), ("sweeper", (2, 2))]
    assert [dataclasses.replace(r, unranked=()) for r in rows] == alone
    assert rows[0].unranked == ("eq20",) and rows[0].scenarios == 1
    data = _data(records, rows)
    md = markdown(data, (None, "not needed"))
    table = md[md.index("### Not ranked: eq20") : md.index("Intervals are 95%")]
    assert "| steady | eq20 | 15/30 = 0.50" in table and "| sweeper | eq20 | 30/30 = 1.00" in table
    assert "| s1 |" not in table and "## eq20" in md  # its own section stays
    assert "<h3>Not ranked: eq20</h3>" in html_page(data, _images(data), (None, "not needed"))


def test_a_scenario_says_whether_it_is_ranked(tmp_path):
    path = tmp_path / "eq20.yaml"
    path.write_text("ranked: false\ncapture_tolerance: 0.001\n")
    assert load_scenario(path).ranked is False and Scenario().ranked is True
    loads = {"eq20": load_scenario(path), "s1": Scenario()}

    def load(name: str) -> Scenario:
        if name not in loads:
            raise ConfigError(f"unknown scenario {name!r}")
        return loads[name]

    assert unranked_scenarios(["s1", "eq20", "nowhere", "eq20"], load) == ("eq20",)
    assert unranked_scenarios(["nowhere_shipped"]) == ()  # a name that does not load is ranked
    assert counted_scenarios(["s1", "eq20"], {"eq20"}) == ["s1"]
    assert counted_scenarios(["eq20"], {"eq20"}) == ["eq20"]  # nothing else to rank over


def test_results_json_keeps_the_intervals_and_older_files_still_read(plain):
    rows = ranked(plain)
    written = json.loads(json.dumps(_sanitise([r.__dict__ for r in rows])))  # as _write_all
    assert [RankingRow.from_json(w) for w in written] == rows
    assert written[1]["rank_low"] == 2 and written[1]["tie_last"] == 3
    old = {k: v for k, v in written[0].items() if k not in ("rank_low", "rank_high", "tie_first",
           "tie_last", "unranked", "mean_relative_speed_median")}  # fmt: skip
    read = RankingRow.from_json(old)
    assert (read.rank, read.rank_low, read.tie_first, read.unranked) == (1, None, None, ())
    assert ranking_cells(read)[3:5] == ["—", "—"]


def _scenario(tolerance: float, v_max: float | None, hold: float) -> Scenario:
    return Scenario().replace(capture_tolerance=tolerance, capture={"v_max": v_max, "hold": hold})


def test_the_capture_rule_in_one_sentence_with_and_without_a_speed_bound():
    envelope, eq20 = _scenario(0.005, 0.05, 0.3), _scenario(0.001, None, 0.0)
    assert capture_rule(envelope) == (
        "the end-effector within 5 mm of the capture point (each axis), moving at most 50 mm/s "
        "relative to it, both for 0.3 s"
    )
    assert capture_rule(eq20) == (
        "the end-effector within 1 mm of the capture point (each axis), at any speed, at one "
        "instant"
    )
    assert capture_rule(_scenario(0.01, None, 0.2)).endswith("at any speed, for 0.2 s")
    both = capture_rule_text(["a", "b", "c"], {"a": envelope, "b": eq20, "c": envelope})
    assert both == (f"A capture: on a and c, {capture_rule(envelope)}; on b, {capture_rule(eq20)}.")
    assert capture_rule_text(["a", "c"], {"a": envelope, "c": envelope}) == (
        f"A capture: {capture_rule(envelope)}."
    )
    assert "x, as its scenario file says" in capture_rule_text(["x"], {})


def test_the_capture_rule_is_the_reports_first_line(plain):
    records = [dataclasses.replace(r, scenario="paper") for r in plain if r.scenario == "s1"]
    data = _data(records, rank_agents(summarise_all(records, reference_agent="best")))
    sentence = report_capture_rule(data)
    assert sentence == f"A capture: {capture_rule(load_scenario('paper'))}."
    md = markdown(data, (None, "not needed")).splitlines()
    assert md[0].startswith("# ") and md[2] == sentence and md[4] == READING
    assert md[6] == "Regenerate with:"
    page = html_page(data, _images(data), (None, "not needed"))
    h1 = page.index("</h1>")
    assert page.index(sentence) - h1 < 30 and page.index(sentence) < page.index("<figure")
    assert (
        page.index(sentence)
        < page.index(html.escape(READING))
        < page.index("<h2>Overall ranking</h2>")
    )


def _data(records: list[EpisodeRecord], ranking: list[RankingRow]) -> ReportData:
    summaries = summarise_all(records, reference_agent="best")
    return ReportData("synthetic", "synthetic records", "python evaluate.py", "best", records,
                      summaries, ranking, {"seeds": {}})  # fmt: skip


def _images(data: ReportData) -> dict[str, bytes]:
    """Stand-in figures: the page's text is what these tests read."""
    from capture_bench.evaluation.reporting.report import figure_names

    return {name: b"\x89PNG" for name in figure_names(data)}
