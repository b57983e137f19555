"""Write the leaderboard report of one suite into ``<out>/<suite>/``.

Files: ``leaderboard.md`` (headed by the command that regenerates it), ``leaderboard.html`` (one
self-contained file, figures embedded as base64 PNG and the episodes to watch as base64 GIF),
``results.csv`` (one row per agent x scenario), ``episodes.csv`` (one row per episode),
``results.json`` (rows, ranking, the rliable statistics, provenance), the PNG figures and the
GIFs. Everything is written into a temporary directory next to the target and renamed into place
at the end, so a failed run never leaves a half-written report. The renaming is one step that
Ctrl-C and SIGTERM do not cut: one that comes during it is raised once the new report is in place,
and `reports_written` says so to the command, whose message then names the report written.
"""

from __future__ import annotations

import contextlib
import csv
import html
import json
import math
import os
import re
import shutil
import tempfile
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from capture_bench.evaluation.errors import EvaluationError
from capture_bench.evaluation.reporting import (
    pixel_comparison,
    plots,
    rliable_report,
    summary,
    training_seeds,
    vision,
    vision_cost,
    watch,
)
from capture_bench.evaluation.reporting.aggregate import (
    RANKING_RULE,
    RankingRow,
    Summary,
    failure_reasons,
    summary_row,
    with_rank_intervals,
)
from capture_bench.evaluation.reporting.metrics import Estimate
from capture_bench.evaluation.reporting.paired import Paired, PairedSection
from capture_bench.evaluation.reporting.rliable_report import RliableSection
from capture_bench.evaluation.running.rollout import EPISODE_COLUMNS, EpisodeRecord
from capture_bench.evaluation.running.suites import VALIDATION_SUFFIX
from capture_bench.interrupts import interrupts_deferred
from capture_bench.provenance import REPRODUCIBILITY, provenance_text
from capture_bench.task.scenarios import ConfigError, Scenario, load_scenario

if TYPE_CHECKING:
    from capture_bench.evaluation.running.video import EpisodeVideo

CSV_FILES = ("results.csv", "episodes.csv")
#: The episodes on the scenarios' twins (`ReportData.twin_records`), where the report has any.
TWINS_CSV = "twin_episodes.csv"
#: The section "Aggregate statistics (rliable)": its numbers, or None and why it has none.
RliableNumbers = tuple[RliableSection | None, str | None]


@dataclass(frozen=True)
class ReportData:
    """Everything a report shows.

    Attributes:
        suite: suite name (the report directory's name).
        description: the suite's description.
        command: the exact command line that regenerates the report.
        reference: agent of the paired comparison.
        records: every episode, in a deterministic order.
        summaries: one per agent x scenario.
        ranking: the overall ranking; a ranking without rank intervals gets them here, from
            ``records`` (`with_rank_intervals`).
        provenance: JSON-ready provenance (git, hashes, versions, seeds, timing).
        videos: the episodes to watch (`capture_bench.evaluation.reporting.watch`), in display
            order.
        training_seeds: per agent of a model shipped from several training seeds, its scores
            over them (`capture_bench.evaluation.reporting.training_seeds`); empty where no
            agent has any, and the report is then without the section and the column.
        twin_records: the episodes on the scenarios' twins, not ranked (the truth-fed
            ``X_truth`` and the rendered ``X_rendered`` of a suite that plays them,
            `capture_bench.evaluation.reporting.vision_cost`); written to `TWINS_CSV`.
    """

    suite: str
    description: str
    command: str
    reference: str
    records: Sequence[EpisodeRecord]
    summaries: Sequence[Summary]
    ranking: Sequence[RankingRow]
    provenance: dict[str, Any]
    videos: Sequence[EpisodeVideo] = ()
    training_seeds: dict[str, training_seeds.SeedScores] = field(default_factory=dict)
    twin_records: Sequence[EpisodeRecord] = ()

    def __post_init__(self) -> None:
        if self.records and any(r.rank is not None and r.rank_low is None for r in self.ranking):
            object.__setattr__(self, "ranking", with_rank_intervals(self.ranking, self.records))


def csv_value(value: Any) -> Any:
    """CSV cell: NaN -> empty, floats at full precision (repr), others as they are."""
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return value


def json_value(value: Any) -> Any:
    """JSON-safe value: NaN -> null, +-inf -> "inf"/"-inf"."""
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


def _fmt(value: float, digits: int = 2) -> str:
    if math.isnan(value):
        return "—"
    return "∞" if math.isinf(value) else f"{value:.{digits}f}"


def fmt_estimate(est: Estimate, digits: int = 2) -> str:
    """``value [low, high]``; dashes where undefined."""
    if math.isnan(est.value):
        return "—"
    if math.isnan(est.low):
        return _fmt(est.value, digits)
    return f"{_fmt(est.value, digits)} [{_fmt(est.low, digits)}, {_fmt(est.high, digits)}]"


MAIN_HEADER = (
    "agent",
    "capture rate",
    "median time, s",
    "IQM time, s",
    "KM median time, s",
    "median ratio to limit",
    "P(better than ref)",
    "paired Δt, s",
    "failures",
)
DETAIL_HEADER = (
    "agent",
    "distance at capture, mm",
    "rel. speed at capture, mm/s",
    "position RMSE, mm",
    "velocity RMSE, mm/s",
    "NEES",
    "path length, m",
    "saturated steps",
)


def main_cells(s: Summary, reference: str) -> list[str]:
    """One row of the main per-scenario table."""
    f = s.figures
    failures = ", ".join(f"{k} {v}" for k, v in sorted(s.failures.items())) or "none"
    paired = s.paired
    return [
        s.agent + (" (reference)" if s.agent == reference else ""),
        f"{s.captured}/{s.episodes} = {fmt_estimate(s.capture_rate)}",
        fmt_estimate(f["capture_time_median"]),
        fmt_estimate(f["capture_time_iqm"]),
        fmt_estimate(s.km_median),
        fmt_estimate(f["ratio_median"]),
        fmt_estimate(paired.prob_improvement) if paired else "—",
        fmt_estimate(paired.time_difference, 3) if paired else "—",
        failures,
    ]


def _scaled(est: Estimate, scale: float) -> Estimate:
    return Estimate(est.value * scale, est.low * scale, est.high * scale)


def detail_cells(s: Summary) -> list[str]:
    """One row of the per-scenario detail table (units in the header)."""
    f = s.figures
    return [
        s.agent,
        fmt_estimate(_scaled(f["distance_at_capture_median"], 1e3)),
        fmt_estimate(_scaled(f["relative_speed_at_capture_median"], 1e3)),
        fmt_estimate(_scaled(f["position_rmse_mean"], 1e3)),
        fmt_estimate(_scaled(f["velocity_rmse_mean"], 1e3)),
        fmt_estimate(f["nees_mean"]),
        fmt_estimate(f["path_length_mean"]),
        fmt_estimate(f["saturated_share_mean"]),
    ]


def ranking_cells(r: RankingRow) -> list[str]:
    """One row of the overall ranking: rank, agent, mean capture rate, 95% rank interval
    (``low–high``), tie group (``ranks first–last``, "—" for an agent tied with no one), mean
    median ratio, mean median relative speed, scenarios counted."""
    name = r.agent + (" (privileged)" if r.privileged else "")
    interval = "—" if r.rank_low is None else f"{r.rank_low}–{r.rank_high}"
    return [
        "—" if r.rank is None else str(r.rank),
        name,
        f"{r.mean_capture_rate:.3f}",
        interval,
        f"ranks {r.tie_first}–{r.tie_last}" if r.tied else "—",
        _fmt(r.mean_ratio_median),
        _fmt(r.mean_relative_speed_median * 1e3, 0),
        str(r.scenarios),
    ]


def ranking_table(data: ReportData) -> tuple[list[str], list[list[str]]]:
    """The overall ranking's header and rows (`RANKING_HEADER`, `ranking_cells`), with the
    truth-fed mean capture rate (`vision_cost.COLUMN`) beside the mean capture rate where an
    agent played the truth-fed twins, and the column of the training seeds' IQM
    (`training_seeds.COLUMN`) where an agent has seeds."""
    header, rows = list(RANKING_HEADER), [ranking_cells(r) for r in data.ranking]
    truth = truth_fed_rates(data)
    if truth:
        at = header.index("mean capture rate") + 1
        header.insert(at, vision_cost.COLUMN)
        for r, row in zip(data.ranking, rows):
            row.insert(at, vision_cost.ranking_cell(truth, r.agent))
    if data.training_seeds:
        header.append(training_seeds.COLUMN)
        for r, row in zip(data.ranking, rows):
            row.append(training_seeds.ranking_cell(data.training_seeds, r.agent))
    return header, rows


def scenario_notes(data: ReportData) -> str:
    """The text before the per-scenario tables (`NOTES`), saying which policy a learned row
    plays where an agent has training seeds."""
    return NOTES + (f" {training_seeds.ROW_POLICY}" if data.training_seeds else "")


RANKING_HEADER = (
    "rank",
    "agent",
    "mean capture rate",
    "rank interval (95%)",
    "tie group",
    "mean median ratio",
    "mean median rel. speed at capture, mm/s",
    "scenarios",
)
NOTES = (
    "Intervals are 95%: Wilson for the capture rate, percentile bootstrap (scipy.stats.bootstrap, "
    "fixed seed) otherwise. Times and ratios are over captured episodes; the KM median treats "
    "failures as censored at their end time. P(better than ref) and paired Δt compare with the "
    "reference agent seed by seed: a failure is worse than any capture, ties count 1/2, and Δt "
    "uses only seeds both captured (negative = faster). These intervals are per comparison (one "
    "agent against the reference on one scenario), not corrected for multiple comparisons: "
    "across the report's many agent x scenario cells some will exclude the no-difference value "
    "by chance, and the report decides nothing from them."
)
NOT_RANKED_HEADER = ("agent", "scenario", "capture rate", "median ratio to limit")


def paired_cells(c: Paired, first: str, reference: str) -> list[str]:
    """One row of a paired table (`capture_bench.evaluation.reporting.paired`), labelled by the
    comparison's attribute ``first``."""
    label = getattr(c, first)
    return [
        label + (" (reference)" if label == reference else ""),
        str(c.seeds),
        f"{c.captured_a}/{c.seeds} = {fmt_estimate(c.capture_rate_a)}",
        f"{c.captured_b}/{c.seeds} = {fmt_estimate(c.capture_rate_b)}",
        fmt_estimate(c.capture_rate_difference),
        f"{c.only_a} / {c.only_b} / {c.both_captured}",
        fmt_estimate(c.ratio_median_a),
        fmt_estimate(c.ratio_median_b),
        fmt_estimate(c.ratio_difference),
    ]


def ranked_scenarios(data: ReportData) -> list[str]:
    """The report's scenarios that count in the ranking."""
    left_out = set(not_ranked(data))
    return [name for name in _scenarios(data) if name not in left_out]


def truth_fed_rates(data: ReportData) -> dict[str, float]:
    """Per agent that played the truth-fed twins, its mean truth-fed capture rate over the
    ranked scenarios (`vision_cost.truth_fed_rates`)."""
    return vision_cost.truth_fed_rates(data.twin_records, ranked_scenarios(data))


def paired_sections(data: ReportData) -> list[PairedSection]:
    """The report's paired sections, where it holds what they compare: each agent fed the
    estimate against the truth (`capture_bench.evaluation.reporting.vision_cost`), rendered
    against analytic vision (`capture_bench.evaluation.reporting.vision`, on the scenarios and
    their twins), pixels against the estimate
    (`capture_bench.evaluation.reporting.pixel_comparison`)."""
    models = data.provenance.get("config_hashes", {}).get("models", {})
    found = (
        vision_cost.section(data.records, data.twin_records, ranked_scenarios(data)),
        vision.section(vision_cost.vision_records(data.records, data.twin_records)),
        pixel_comparison.section(data.records, data.reference, models),
    )
    return [s for s in found if s is not None]


def _section_tables(section: PairedSection, reference: str) -> list[tuple[str, list[list[str]]]]:
    return [
        (title, [paired_cells(c, section.first, reference) for c in comparisons])
        for title, comparisons in section.tables
    ]


def _md_table(header: Sequence[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in rows]


def _scenarios(data: ReportData) -> list[str]:
    return list(dict.fromkeys(s.scenario for s in data.summaries))


def scenario_configs(data: ReportData) -> dict[str, Scenario]:
    """Each scenario of the report that loads, by its name in the report: a file the
    provenance's seeds name by path (under the name it has), else the shipped scenario of that
    name."""
    by_path: dict[str, Scenario] = {}
    seeds = data.provenance.get("seeds")
    for spec in seeds if isinstance(seeds, dict) else ():
        if Path(str(spec)).suffix in (".yaml", ".yml"):
            with contextlib.suppress(ConfigError):
                loaded = load_scenario(str(spec))
                by_path.setdefault(loaded.name, loaded)
    out: dict[str, Scenario] = {}
    for name in _scenarios(data):
        if name in by_path:
            out[name] = by_path[name]
            continue
        with contextlib.suppress(ConfigError):
            out[name] = load_scenario(name)
    return out


def capture_rule(scenario: Scenario) -> str:
    """The scenario's capture rule in words: the box of eq. 20 (``capture_tolerance``), the bound
    on the relative speed (``capture.v_max``) and how long both must hold (``capture.hold``)."""
    box = (
        f"the end-effector within {scenario.capture_tolerance * 1e3:.4g} mm of the capture point "
        "(each axis)"
    )
    v_max, hold = scenario.capture.v_max, scenario.capture.hold
    speed = (
        "at any speed" if v_max is None else f"moving at most {v_max * 1e3:.4g} mm/s relative to it"
    )
    if hold <= 0:
        when = "at one instant"
    else:
        when = f"{'for' if v_max is None else 'both for'} {hold:.4g} s"
    return f"{box}, {speed}, {when}"


#: The rule of a scenario whose file is not at hand where the report is written.
UNKNOWN_RULE = "as its scenario file says (not found where this report was written)"


def capture_rule_text(scenarios: Sequence[str], configs: dict[str, Scenario]) -> str:
    """One sentence: the capture rule of ``scenarios`` (names, in order; ``configs`` holds those
    that loaded), each distinct rule once, with the scenarios it holds on where they differ."""
    groups: dict[str, list[str]] = {}
    for name in scenarios:
        rule = capture_rule(configs[name]) if name in configs else UNKNOWN_RULE
        groups.setdefault(rule, []).append(name)
    if len(groups) == 1 and UNKNOWN_RULE not in groups:
        return f"A capture: {next(iter(groups))}."
    return "A capture: " + "; ".join(f"on {_listed(n)}, {r}" for r, n in groups.items()) + "."


def _listed(names: Sequence[str]) -> str:
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def report_capture_rule(data: ReportData) -> str:
    """The report's first line under its title: the capture rule of the scenarios evaluated."""
    return capture_rule_text(_scenarios(data), scenario_configs(data))


def not_ranked(data: ReportData) -> list[str]:
    """The report's scenarios that count in no average of the ranking (``ranked: false``)."""
    left_out = {name for r in data.ranking for name in r.unranked}
    return [name for name in _scenarios(data) if name in left_out]


NOT_RANKED_TEXT = (
    "These scenarios say ranked: false: they count in none of the ranking's averages and in "
    "none of its rank intervals. Their own sections below have every figure."
)


def not_ranked_rows(data: ReportData) -> list[list[str]]:
    """The table of the scenarios not ranked: per scenario, each agent (ranking order) with its
    capture rate and median ratio to the physical limit there."""
    cells = {(s.agent, s.scenario): s for s in data.summaries}
    rows = []
    for scenario in not_ranked(data):
        for r in data.ranking:
            s = cells.get((r.agent, scenario))
            if s is not None:
                rows.append(
                    [
                        r.agent + (" (privileged)" if r.privileged else ""),
                        scenario,
                        f"{s.captured}/{s.episodes} = {fmt_estimate(s.capture_rate)}",
                        fmt_estimate(s.figures["ratio_median"]),
                    ]
                )
    return rows


def _title(data: ReportData, quote: str) -> str:
    """``default suite``, ``custom-<hash> (custom selection)`` or ``merged-<hash> (merged
    reports)``: never a suite's name for a narrowed run or a merge; a run on the validation
    seeds says so."""
    name = f"{quote}{data.suite}{quote}"
    if data.suite.startswith("custom-"):
        title = f"{name} (a custom selection, not a suite as defined)"
    elif data.suite.startswith("merged-"):
        title = f"{name} (reports merged from several evaluations)"
    else:
        title = f"{name} suite"
    if data.suite.endswith(VALIDATION_SUFFIX):
        title += ", on validation seeds (for choosing models, not a leaderboard)"
    return title


SUMMARY_FIGURES = ("summary_heatmap.png", "summary_ranking.png", "summary_improvement.png")
#: What the report's numbers mean: said under the capture rule at the top of both pages.
READING = (
    "The physical limit of an episode is the earliest time at which any motion of the arm within "
    "its joint-velocity limits could satisfy the capture rule above, computed from the target's "
    "true motion (privileged: no agent knows it, and none can capture sooner). The ratio to the "
    "limit is capture time / physical limit: 1.00x is as fast as physically possible, 1.13x is "
    "13% slower. Agents are ranked by capture rate, then by that ratio."
)
OUTCOME_FIGURES = ("failures_by_reason.png", "ratio_to_limit.png")
OUTCOMES_TITLE = "Outcomes and ratio to the physical limit"
SCENARIOS_TITLE = "Per scenario"


def _agents(data: ReportData) -> list[str]:
    """Every agent in ranking order (privileged last)."""
    return [r.agent for r in data.ranking]


def scenario_summaries(data: ReportData, scenario: str) -> list[Summary]:
    """The summaries of ``scenario`` in the ranking's order (an agent the ranking lacks after
    those it holds, in the order of ``data.summaries``)."""
    order = {agent: k for k, agent in enumerate(_agents(data))}
    cells = [s for s in data.summaries if s.scenario == scenario]
    return sorted(cells, key=lambda s: order.get(s.agent, len(order)))


def summary_text(data: ReportData) -> str:
    """One sentence on the tie groups of the ranking: the agents the seeds cannot order."""
    groups: dict[int, list[str]] = {}
    for r in data.ranking:
        if r.tied and r.tie_first is not None:
            groups.setdefault(r.tie_first, []).append(r.agent)
    if not groups:
        return (
            "No two agents are tied: the 95% rank interval of each agent is clear of the "
            "interval of the agent ranked just above it."
        )
    listed = "; ".join(
        f"ranks {first}–{first + len(agents) - 1}: {', '.join(agents)}"
        for first, agents in groups.items()
    )
    return (
        "Tied, the seeds cannot order them (the 95% rank interval of each agent overlaps that "
        f"of the agent ranked just above it): {listed}."
    )


def rliable_numbers(data: ReportData) -> RliableNumbers:
    """The section "Aggregate statistics (rliable)"
    (`capture_bench.evaluation.reporting.rliable_report`) of ``data``: ``(its numbers, None)``, or
    ``(None, why the records make no score matrices)``."""
    agents = _agents(data)
    reason = rliable_report.unavailable(data.records, agents)
    if reason is not None:
        return None, reason
    return rliable_report.compute(data.records, agents, data.reference), None


def rliable_rows(data: ReportData, section: RliableSection) -> list[list[str]]:
    """The rows of the rliable table, agents labelled as in the ranking."""
    privileged = {r.agent for r in data.ranking if r.privileged}

    def label(agent: str) -> str:
        if agent == data.reference:
            return f"{agent} (reference)"
        return agent + (" (privileged)" if agent in privileged else "")

    return [rliable_report.cells(section, agent, label(agent)) for agent in section.agents]


def _has_profile(data: ReportData) -> bool:
    return rliable_report.unavailable(data.records, _agents(data)) is None


def figure_names(data: ReportData) -> list[str]:
    """File names of the figures, in display order (the summary's first, then the performance
    profile where the rliable section has numbers)."""
    survival = [f"survival_{scenario}.png" for scenario in _scenarios(data)]
    profile = [rliable_report.FIGURE] if _has_profile(data) else []
    return [*SUMMARY_FIGURES, *profile, *survival, "failures_by_reason.png", "ratio_to_limit.png"]


def figures(data: ReportData, names: Sequence[str] | None = None) -> dict[str, bytes]:
    """Render the figures ``names`` (default every one, `figure_names`): file name -> PNG
    bytes; one colour (and, in the curves, one line style) per agent throughout, agents in the
    ranking's order. Each figure depends on ``data`` alone, so any split of the names draws the
    same bytes."""
    wanted = figure_names(data) if names is None else list(names)
    agents = _agents(data)
    colours = plots.agent_colours(agents, data.reference)
    styles = plots.agent_line_styles(agents, data.reference)
    scenarios = _scenarios(data)
    top = plots.improvement_agents(agents)

    def survival(scenario: str) -> bytes:
        cells = scenario_summaries(data, scenario)
        return plots.survival_figure(scenario, cells, colours, data.reference, styles)

    def heatmap() -> bytes:
        rate, ratio = summary.heatmap_cells(data.summaries, agents, scenarios)
        return plots.heatmap_figure(rate, ratio, agents, scenarios)

    draw = {
        "summary_heatmap.png": heatmap,
        "summary_ranking.png": lambda: plots.ranking_figure(
            summary.ranking_intervals(data.records, data.ranking), colours
        ),
        "summary_improvement.png": lambda: plots.improvement_figure(
            summary.probability_of_improvement(data.records, top), top
        ),
        rliable_report.FIGURE: lambda: plots.performance_profile_figure(
            rliable_report.profiles(data.records, agents), colours, data.reference, styles
        ),
        **{f"survival_{sc}.png": (lambda sc=sc: survival(sc)) for sc in scenarios},
        "failures_by_reason.png": lambda: plots.failures_figure(
            data.summaries, failure_reasons(data.summaries), agents
        ),
        "ratio_to_limit.png": lambda: plots.ratio_figure(
            data.records, colours, data.reference, agents
        ),
    }
    unknown = [name for name in wanted if name not in draw]
    if unknown:
        raise ValueError(f"no figure named {unknown[0]!r}; the report's: {', '.join(draw)}")
    return {name: draw[name]() for name in wanted}


def figure_groups(data: ReportData, groups: int) -> list[list[str]]:
    """`figure_names` in ``groups`` lists of about equal drawing time, to draw in as many
    processes: the costliest figures (the ratio box plots, the performance profile with rliable's
    import and bootstrap, the probability of improvement and its bootstrap, the failure bars) each
    lead a group, the others dealt round."""
    names = figure_names(data)
    heavy = [
        "ratio_to_limit.png",
        rliable_report.FIGURE,
        "summary_improvement.png",
        "failures_by_reason.png",
    ]
    order = [n for n in heavy if n in names] + [n for n in names if n not in heavy]
    out: list[list[str]] = [[] for _ in range(max(1, min(groups, len(order))))]
    for k, name in enumerate(order):
        out[k % len(out)].append(name)
    return out


@dataclass(frozen=True)
class FigureText:
    """What the report says of one figure: ``alt``, what it shows (the image's alternative
    text); ``caption``, that and how to read it."""

    alt: str
    caption: str


def _n(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def _ranking_reading(data: ReportData) -> str:
    panels, floor = plots.ranking_layout(summary.ranking_intervals(data.records, data.ranking))
    text = (
        "Dot: the mean capture rate; bar: its 95% paired-bootstrap interval over the seeds; "
        'label: rank, agent and 95% rank interval. A shaded band (and "=") groups agents whose '
        "rank intervals overlap: the seeds cannot order them."
    )
    limits = [plots.panel_limits(p) for p in panels]
    if len(panels) == 2:
        (a, b), (c, d) = limits
        text += (
            f" The rates fall far between ranks {panels[0][-1].row.rank} and "
            f"{panels[1][0].row.rank}, so the agents are drawn in two panels, each on its own x "
            f"axis (capture rate {a:.2f} to {b:.2f} above, {c:.2f} to {d:.2f} below): the top "
            "agents, a few episodes apart, are resolved, and so are the weak ones; compare "
            "positions within a panel only."
        )
    elif limits:
        low, high = limits[0]
        text += f" The x axis spans the agents drawn: capture rate {low:.2f} to {high:.2f}."
    note = plots.not_drawn_note(floor)
    return f"{text} {note}" if note else text


def figure_text(data: ReportData, name: str) -> FigureText:
    """The alternative text and the caption of the figure ``name`` of ``data``'s report."""
    agents, scenarios, ref = _agents(data), _scenarios(data), data.reference
    n_agents, n_scenarios = _n(len(agents), "agent"), _n(len(scenarios), "scenario")
    emphasis = (
        f"The reference, {ref}, is black and thicker; every agent has the same colour (and line "
        "style) in every figure."
    )
    if name == "summary_heatmap.png":
        alt = (
            f"Heatmap of the capture rate and the median ratio to the physical limit of each of "
            f"the {n_agents} (rows, in ranking order) on each of the {n_scenarios} (columns)."
        )
        read = (
            "Colour: the capture rate, in classes that spend the colours near the top "
            f"({', '.join(plots.rate_classes())}), so that 86% and 100% differ at a glance. Text: "
            "the capture rate and the median ratio of capture time to the physical limit over "
            "the captured episodes (1.00x = as fast as physically possible); a cell without a "
            "ratio captured nothing."
        )
    elif name == "summary_ranking.png":
        ranked = sum(r.rank is not None for r in data.ranking)
        alt = (
            f"Chart of the overall ranking of the {_n(ranked, 'ranked agent')}: each one's mean "
            "capture rate over the ranked scenarios with its 95% interval, best at the top."
        )
        read = _ranking_reading(data)
    elif name == "summary_improvement.png":
        top = plots.improvement_agents(agents)
        of = (
            f" (of {len(agents)}; the rliable section compares every agent)"
            if len(top) < len(agents)
            else ""
        )
        alt = (
            f"Matrix of the probability of improvement between the top {len(top)} agents by "
            f"rank{of}."
        )
        read = (
            "Each cell: the probability that an episode of the row's agent scores higher than an "
            "episode of the column's agent (columns numbered as the rows; score = physical limit "
            "/ capture time, 0 for a failure; ties count half), averaged over the scenarios. "
            "Above 0.5 (blue) the row's agent is the better, below 0.5 (red) the worse; 0.5 is a "
            "coin toss."
        )
    elif name == rliable_report.FIGURE:
        alt = (
            f"Line chart of the performance profiles of the {n_agents}: the share of each agent's "
            "episodes, over every scenario, scoring above each threshold."
        )
        read = (
            "x: the score threshold τ (score = physical limit / capture time, 0 for a failure); "
            "y: the share of the agent's episodes scoring above τ, with its 95% stratified "
            "bootstrap band. Higher is better: a curve's height near τ = 0 is the capture rate, "
            f"and a curve that stays high toward τ = 1 captures close to the physical limit. "
            f"{emphasis}"
        )
    elif name.startswith("survival_") and name[len("survival_") : -len(".png")] in scenarios:
        scenario = name[len("survival_") : -len(".png")]
        alt = (
            f"Survival curves on {scenario}: for each of the {n_agents}, the share of episodes "
            "not yet captured against the time since the episode started."
        )
        read = (
            "Kaplan-Meier estimates with 95% bands; a failed episode counts until it ended "
            "(censored). A curve that falls sooner captures faster; the level where it ends is "
            f"the share never captured. {emphasis}"
        )
    elif name == "failures_by_reason.png":
        alt = (
            f"Bar chart of the outcomes of each agent's episodes on each of the {n_scenarios}: "
            "the share captured and the share failed for each reason."
        )
        read = (
            "One panel per scenario, one bar per agent (in ranking order): the share of its "
            "episodes captured (green), then the share that failed for each reason (legend "
            "below): timeout, collision, target lost, unreachable."
        )
    elif name == "ratio_to_limit.png":
        alt = (
            "Box plots of the ratio of capture time to the physical limit of each agent's "
            f"captured episodes on each of the {n_scenarios}."
        )
        read = (
            "One panel per scenario, one row per agent (in ranking order), one logarithmic x "
            "axis for every panel: the box spans the middle half of the captured episodes, the "
            "line in it is the median, whiskers reach 1.5 box lengths, circles are outliers; the "
            'dashed line at 1 is the physical limit. "no capture": none to show.'
        )
    else:
        raise ValueError(f"no figure named {name!r}; the report's: {', '.join(figure_names(data))}")
    return FigureText(alt, f"{alt} {read}")


def _html_table(header: Sequence[str], rows: list[list[str]]) -> str:
    """A table in a box of its own that scrolls sideways where the page is narrower."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows
    )
    return (
        f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody>'
        "</table></div>"
    )


#: The page's style: one column that fits a phone (tables and code scroll inside their boxes,
#: images shrink to the column), figures at their natural size on a desktop.
STYLE = (
    "html{-webkit-text-size-adjust:100%}"
    "body{font-family:system-ui,sans-serif;line-height:1.45;max-width:76em;margin:0 auto;"
    "padding:0.5em 1em 2em;overflow-wrap:break-word}"
    "@media (min-width:48em){body{padding:1em 2em 3em}}"
    "h1{font-size:1.6em;line-height:1.25}"
    ".scroll{overflow-x:auto;max-width:100%;margin:1em 0}"
    "table{border-collapse:collapse;font-size:0.9em}"
    "th,td{border:1px solid #ccc;padding:0.3em 0.6em;text-align:left;vertical-align:top}"
    "th{background:#f3f3f3}img{max-width:100%;height:auto}"
    "figure{margin:1.5em 0}figcaption{font-size:0.9em;color:#333;max-width:62em}"
    "code,pre{background:#f6f6f6}code{padding:0 0.2em}"
    "pre{padding:0.5em;overflow-x:auto;white-space:pre-wrap;overflow-wrap:anywhere}"
    "nav.toc{background:#f7f7f7;border:1px solid #ddd;border-radius:4px;padding:0.4em 0.8em;"
    "margin:1em 0}nav.toc ul{margin:0;padding:0;list-style:none;display:flex;flex-wrap:wrap;"
    "gap:0.2em 1.2em}nav.toc li ul{display:inline-flex;gap:0.2em 0.7em}"
    ".run{font-size:0.9em;color:#333}" + watch.STYLE
)
VIEWPORT = '<meta name="viewport" content="width=device-width, initial-scale=1">'


def _figure(data: ReportData, name: str, images: dict[str, bytes]) -> str:
    """A figure embedded as base64 (the page stays one file) with its caption."""
    text = figure_text(data, name)
    return watch.embedded_figure(images[name], "image/png", text.caption, alt=text.alt)


def _anchor(prefix: str, name: str, taken: set[str]) -> str:
    """An id for ``name``, of letters, digits, ``_`` and ``-``, not in ``taken`` (then in it)."""
    base = prefix + re.sub(r"[^A-Za-z0-9_-]+", "-", name)
    anchor, k = base, 1
    while anchor in taken:
        k += 1
        anchor = f"{base}-{k}"
    taken.add(anchor)
    return anchor


@dataclass(frozen=True)
class _Section:
    anchor: str
    title: str
    body: list[str]
    children: tuple[tuple[str, str], ...] = ()  # (anchor, title) of its parts in the contents


def _toc(sections: Sequence[_Section]) -> str:
    esc = html.escape
    items = []
    for s in sections:
        link = f'<a href="#{s.anchor}">{esc(s.title)}</a>'
        if s.children:
            inner = "".join(f'<li><a href="#{a}">{esc(t)}</a></li>' for a, t in s.children)
            link += f": <ul>{inner}</ul>"
        items.append(f"<li>{link}</li>")
    return f'<nav class="toc" aria-label="Contents"><ul>{"".join(items)}</ul></nav>'


def html_page(
    data: ReportData, images: dict[str, bytes], rliable: RliableNumbers | None = None
) -> str:
    """The leaderboard as one self-contained HTML page (images inlined as base64); ``rliable``:
    the `rliable_numbers` of ``data`` if already computed.

    Its first screen: the title, the capture rule (`report_capture_rule`), what the physical
    limit and the ratio to it are (`READING`), the run, the contents (a link to every section),
    then the overall ranking. Every image is a ``<figure>`` with its caption (`figure_text`);
    the page fits a phone's width (`STYLE`, `VIEWPORT`)."""
    esc = html.escape
    stats, why = rliable_numbers(data) if rliable is None else rliable
    sections = [
        _Section("ranking", "Overall ranking", _ranking_html(data, images)),
        _Section(
            "summary",
            "Summary",
            [
                "<h2>Summary</h2>",
                *(_figure(data, n, images) for n in SUMMARY_FIGURES if n != "summary_ranking.png"),
            ],
        ),
    ]
    if data.videos:
        sections.append(_Section("watch", watch.TITLE, [watch.html_section(data.videos)]))
    rliable_body = [f"<h2>{esc(rliable_report.TITLE)}</h2>"]
    if stats is None:
        rliable_body.append(f"<p>Left out: {esc(str(why))}.</p>")
    else:
        rliable_body.append(f"<p>{esc(rliable_report.text(stats))}</p>")
        rliable_body.append(_html_table(rliable_report.HEADER, rliable_rows(data, stats)))
        rliable_body.append(_figure(data, rliable_report.FIGURE, images))
    sections.append(_Section("rliable", rliable_report.TITLE, rliable_body))
    if data.training_seeds:
        seeds = data.training_seeds
        body = [
            f"<h2>{esc(training_seeds.TITLE)}</h2>",
            f"<p>{esc(training_seeds.text(seeds))}</p>",
            _html_table(training_seeds.HEADER, training_seeds.rows(seeds)),
        ]
        sections.append(_Section("seeds", training_seeds.TITLE, body))
    taken = {"ranking", "summary", "watch", "rliable", "seeds", "scenarios", "outcomes",
             "provenance"}  # fmt: skip
    scenario_links = []
    scenario_body = [f"<h2>{SCENARIOS_TITLE}</h2>", f"<p>{esc(scenario_notes(data))}</p>"]
    for scenario in _scenarios(data):
        anchor = _anchor("scenario-", scenario, taken)
        scenario_links.append((anchor, scenario))
        cells = scenario_summaries(data, scenario)
        scenario_body += [
            f'<section id="{anchor}"><h2>{esc(scenario)}</h2>',
            _html_table(MAIN_HEADER, [main_cells(s, data.reference) for s in cells]),
            _html_table(DETAIL_HEADER, [detail_cells(s) for s in cells]),
            _figure(data, f"survival_{scenario}.png", images),
            "</section>",
        ]
    sections.append(_Section("scenarios", SCENARIOS_TITLE, scenario_body, tuple(scenario_links)))
    outcomes = [_figure(data, name, images) for name in OUTCOME_FIGURES]
    sections.append(_Section("outcomes", OUTCOMES_TITLE, [f"<h2>{OUTCOMES_TITLE}</h2>", *outcomes]))
    for section in paired_sections(data):
        body = [f"<h2>{esc(section.title)}</h2><p>{esc(section.text)}</p>"]
        body += [f"<p>{esc(section.left_out)}</p>"] if section.left_out else []
        for title, rows in _section_tables(section, data.reference):
            body.append(f"<h3>{esc(title)}</h3>" + _html_table(section.header, rows))
        sections.append(_Section(_anchor("paired-", section.key, taken), section.title, body))
    provenance = [
        f"<h2>Provenance</h2><p>{esc(provenance_text(data.provenance))}</p>",
        f"<p>{esc(REPRODUCIBILITY)}</p>",
    ]
    sections.append(_Section("provenance", "Provenance", provenance))
    parts = [
        "<!DOCTYPE html>",
        f'<html lang="en"><head><meta charset="utf-8">{VIEWPORT}<title>capture-bench: '
        f"{esc(data.suite)}</title><style>{STYLE}</style></head><body>",
        f"<h1>capture-bench leaderboard: {esc(_title(data, ''))}</h1>",
        f"<p><strong>{esc(report_capture_rule(data))}</strong></p>",
        f"<p>{esc(READING)}</p>",
        f'<p class="run">{_run_text(data)}Regenerate it with <code>{esc(data.command)}</code></p>',
        _toc(sections),
    ]
    for s in sections:
        parts += [f'<section id="{s.anchor}">', *s.body, "</section>"]
    parts.append("</body></html>")
    return "\n".join(parts)


def _run_text(data: ReportData) -> str:
    described = data.description.strip().rstrip(".")
    return f"This run: {html.escape(described)}. " if described else ""


def _ranking_html(data: ReportData, images: dict[str, bytes]) -> list[str]:
    esc = html.escape
    parts = [
        "<h2>Overall ranking</h2>",
        _html_table(*ranking_table(data)),
        _figure(data, "summary_ranking.png", images),
        f"<p>{esc(summary_text(data))}</p>",
        f"<p>{esc(RANKING_RULE)}</p>",
    ]
    unranked = not_ranked(data)
    if unranked:
        parts.append(
            f"<h3>Not ranked: {esc(', '.join(unranked))}</h3><p>{esc(NOT_RANKED_TEXT)}</p>"
        )
        parts.append(_html_table(NOT_RANKED_HEADER, not_ranked_rows(data)))
    return parts


def _md_figure(data: ReportData, name: str) -> list[str]:
    text = figure_text(data, name)
    return [f"![{text.alt}]({name})", "", text.caption, ""]


def markdown(data: ReportData, rliable: RliableNumbers | None = None) -> str:
    """The leaderboard in Markdown: the capture rule, what the physical limit and the ratio are
    (`READING`) and the command that regenerates it, then the sections of `html_page` in the
    same order, each figure with its caption; ``rliable``: the `rliable_numbers` of ``data``
    if already computed."""
    stats, why = rliable_numbers(data) if rliable is None else rliable
    lines = [
        f"# capture-bench leaderboard: {_title(data, '`')}",
        "",
        report_capture_rule(data),
        "",
        READING,
        "",
        "Regenerate with:",
        "",
        "```",
        data.command,
        "```",
        "",
        data.description,
        "",
        "## Overall ranking",
        "",
        *_md_table(*ranking_table(data)),
        "",
        *_md_figure(data, "summary_ranking.png"),
        summary_text(data),
        "",
        RANKING_RULE,
        "",
    ]
    unranked = not_ranked(data)
    if unranked:
        lines += [f"### Not ranked: {', '.join(unranked)}", "", NOT_RANKED_TEXT, ""]
        lines += [*_md_table(NOT_RANKED_HEADER, not_ranked_rows(data)), ""]
    lines += ["## Summary", ""]
    for name in SUMMARY_FIGURES:
        lines += _md_figure(data, name) if name != "summary_ranking.png" else []
    lines += watch.markdown_lines(data.videos)
    lines += [f"## {rliable_report.TITLE}", ""]
    if stats is None:
        lines += [f"Left out: {why}.", ""]
    else:
        rows = rliable_rows(data, stats)
        lines += [rliable_report.text(stats), "", *_md_table(rliable_report.HEADER, rows), ""]
        lines += _md_figure(data, rliable_report.FIGURE)
    lines += seeds_markdown(data)
    lines += [f"## {SCENARIOS_TITLE}", "", scenario_notes(data)]
    for scenario in _scenarios(data):
        cells = scenario_summaries(data, scenario)
        lines += ["", f"## {scenario}", ""]
        lines += _md_table(MAIN_HEADER, [main_cells(s, data.reference) for s in cells])
        lines += ["", *_md_table(DETAIL_HEADER, [detail_cells(s) for s in cells]), ""]
        lines += _md_figure(data, f"survival_{scenario}.png")[:-1]
    lines += ["", f"## {OUTCOMES_TITLE}", ""]
    for name in OUTCOME_FIGURES:
        lines += _md_figure(data, name)
    for section in paired_sections(data):
        left_out = ["", section.left_out] if section.left_out else []
        lines += [f"## {section.title}", "", section.text, *left_out]
        for title, rows in _section_tables(section, data.reference):
            lines += ["", f"### {title}", "", *_md_table(section.header, rows)]
        lines.append("")
    lines += ["## Provenance", "", provenance_text(data.provenance), "", REPRODUCIBILITY, ""]
    return "\n".join(lines)


def seeds_markdown(data: ReportData) -> list[str]:
    """The section "Training seeds" in Markdown; nothing where no agent has training seeds."""
    seeds = data.training_seeds
    if not seeds:
        return []
    table = _md_table(training_seeds.HEADER, training_seeds.rows(seeds))
    return [f"## {training_seeds.TITLE}", "", training_seeds.text(seeds), "", *table, ""]


def _write_csv(path: Path, columns: Sequence[str], rows: list[dict[str, Any]]) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(columns), lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: csv_value(v) for k, v in row.items()})


def read_episodes(path: Path) -> list[EpisodeRecord]:
    """The records of an ``episodes.csv`` that `write_report` wrote, in the file's order,
    every field as written (`EpisodeRecord.from_row`). Raises `EvaluationError`
    naming the file, and the line and column, where it cannot be read."""
    try:
        with open(path, newline="") as handle:
            reader = csv.DictReader(handle)
            records = []
            for row in reader:
                try:
                    records.append(EpisodeRecord.from_row(row))
                except ValueError as exc:
                    raise EvaluationError(f"{path}: line {reader.line_num}: {exc}") from None
            return records
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise EvaluationError(f"{path}: cannot be read ({reason})") from None


def result_rows(data: ReportData) -> list[dict[str, Any]]:
    """The rows of ``results.csv``."""
    reasons = failure_reasons(data.summaries)
    return [summary_row(s, reasons) for s in data.summaries]


def _write_all(data: ReportData, directory: Path, images: dict[str, bytes] | None) -> None:
    rows = result_rows(data)
    _write_csv(directory / "results.csv", list(rows[0]), rows)
    _write_csv(directory / "episodes.csv", EPISODE_COLUMNS, [r.as_row() for r in data.records])
    if data.twin_records:
        twins = [r.as_row() for r in data.twin_records]
        _write_csv(directory / TWINS_CSV, EPISODE_COLUMNS, twins)
    if images is None:
        images = figures(data)
    for name, png in images.items():
        (directory / name).write_bytes(png)
    for video in data.videos:
        (directory / video.file_name).write_bytes(video.gif)
    rliable = rliable_numbers(data)
    (directory / "leaderboard.md").write_text(markdown(data, rliable))
    (directory / "leaderboard.html").write_text(html_page(data, images, rliable))
    payload = {
        "suite": data.suite,
        "command": data.command,
        "reference": data.reference,
        "ranking_rule": RANKING_RULE,
        "ranking": [_ranking_entry(data, r) for r in data.ranking],
        "results": rows,
        "provenance": data.provenance,
    }
    payload[rliable_report.KEY] = rliable_report.payload(*rliable)
    for section in paired_sections(data):  # only where the report holds what they compare
        payload[section.key] = section.rows()
    if data.training_seeds:
        payload[training_seeds.KEY] = training_seeds.payload(data.training_seeds)
    text = json.dumps(_sanitise(payload), indent=2, default=str, allow_nan=False)
    (directory / "results.json").write_text(text + "\n")


def _ranking_entry(data: ReportData, row: RankingRow) -> dict[str, Any]:
    """A ranking row in ``results.json``: its fields, an agent's truth-fed mean capture rate
    where it played the truth-fed twins, and its seed IQM with its interval where it has
    training seeds."""
    entry = dict(row.__dict__)
    truth = truth_fed_rates(data)
    if row.agent in truth:
        entry[vision_cost.RANKING_KEY] = truth[row.agent]
    seeds = data.training_seeds.get(row.agent)
    if seeds is not None:
        entry[training_seeds.RANKING_KEY] = seeds.iqm.as_dict()
    return entry


def _sanitise(o: Any) -> Any:
    if isinstance(o, dict):
        return {k: _sanitise(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_sanitise(v) for v in o]
    return json_value(o)


#: The lists of the `reports_written` blocks open, innermost last.
_WRITTEN: list[list[Path]] = []


@contextlib.contextmanager
def reports_written() -> Iterator[list[Path]]:
    """Within the block, the list it yields gains each report directory `write_report`
    puts in place, as it is put there: what a command stopped by an interrupt has written."""
    written: list[Path] = []
    _WRITTEN.append(written)
    try:
        yield written
    finally:
        _WRITTEN[:] = [w for w in _WRITTEN if w is not written]


def write_report(data: ReportData, out_dir: Path, images: dict[str, bytes] | None = None) -> Path:
    """Write the report into ``out_dir/<suite>/`` atomically; returns that directory.

    ``images``: the `figures` of ``data`` if already drawn (they are drawn here if not).

    The files are written into a temporary sibling directory that replaces the target only once
    complete; on any error the temporary directory is removed and the old report (if any) stays.
    The replacement (the old report moved aside, the new one renamed into place, the old one
    removed) is not cut by Ctrl-C or SIGTERM (in the main thread): one that comes during it is
    raised as it ends, with the new report in place and in `reports_written`'s lists.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / data.suite
    staging = Path(tempfile.mkdtemp(prefix=f".{data.suite}.tmp-", dir=out_dir))
    main_thread = threading.current_thread() is threading.main_thread()
    try:
        _write_all(data, staging, images)
        os.chmod(staging, 0o755)
        with interrupts_deferred() if main_thread else contextlib.nullcontext():
            _put_in_place(staging, target)
            for written in _WRITTEN:
                written.append(target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return target


def _put_in_place(staging: Path, target: Path) -> None:
    """Rename the folder ``staging`` to ``target``, replacing a previous ``target`` folder, which
    is put back if the rename fails and removed if it succeeds."""
    old = None
    if target.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
        os.rmdir(old)
        os.replace(target, old)
    try:
        os.replace(staging, target)
    except BaseException:
        if old is not None:
            os.replace(old, target)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
