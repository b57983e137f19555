"""Episode records -> one summary per agent x scenario, and the overall ranking.

Pure functions of the records (see :mod:`capture_bench.evaluation.metrics` for the statistics).

Ranking rule (:data:`RANKING_RULE`): agents are ranked by their capture rate averaged over the
suite's scenarios (each scenario weighs the same); ties (equal to 1e-9) are broken by the mean over
scenarios of the median ratio to the physical limit (lower first; a scenario with no capture counts
as +inf), then by name. Privileged agents (the ``oracle``, which reads the true trajectory) are
listed as references and not ranked.

Beside the ranking (not part of it), each row shows the mean over scenarios of the median
relative speed at capture, so that a controller that flies through the tolerance box instead of
arriving is visible where the ranking is read.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from capture_bench.evaluation.metrics import (
    Estimate,
    PairedComparison,
    SurvivalCurve,
    bootstrap_estimate,
    kaplan_meier,
    paired_comparison,
    wilson_interval,
)
from capture_bench.evaluation.rollout import EpisodeRecord
from capture_bench.task.step_rule import FAILURES

REFERENCE_AGENT = "incremental_ik"
PRIVILEGED_AGENTS = frozenset({"oracle"})
#: Failure reasons always given a column, in this order; others found are appended sorted.
KNOWN_FAILURES = FAILURES  # the step rule's, in its order
RANKING_RULE = (
    "Ranked by capture rate averaged over scenarios (equal weights); ties broken by the mean over "
    "scenarios of the median capture-time ratio to the physical limit (lower is better, a scenario "
    "with no capture counts as +inf), then by name. Privileged agents (oracle) are references, "
    "not ranked. The median relative speed at capture (mean over the scenarios with a capture) "
    "is shown, not ranked: a fly-through of the tolerance box is fast, an arrival slow."
)

#: (column stem, record field, statistic) for every bootstrap-estimated figure.
ESTIMATED_FIGURES: tuple[tuple[str, str, str], ...] = (
    ("capture_time_median", "capture_time", "median"),
    ("capture_time_iqm", "capture_time", "iqm"),
    ("ratio_median", "ratio", "median"),
    ("distance_at_capture_median", "distance_at_capture", "median"),
    ("relative_speed_at_capture_median", "relative_speed_at_capture", "median"),
    ("position_rmse_mean", "position_rmse", "mean"),
    ("velocity_rmse_mean", "velocity_rmse", "mean"),
    ("nees_mean", "mean_nees", "mean"),
    ("path_length_mean", "path_length", "mean"),
    ("saturated_share_mean", "saturated_share", "mean"),
)


@dataclass(frozen=True)
class Summary:
    """Aggregates of one agent on one scenario.

    Attributes:
        agent, scenario: the cell.
        episodes, captured: counts.
        capture_rate: share captured, Wilson 95% interval.
        figures: column stem -> bootstrap estimate (see :data:`ESTIMATED_FIGURES`).
        km_median: Kaplan-Meier median time to capture (failures censored), s; inf if the
            survival curve never reaches 1/2.
        survival: the Kaplan-Meier curve itself.
        failures: reason -> count.
        paired: comparison with the reference agent (None for the reference itself or if absent).
        wall_clock_s_mean: mean episode wall-clock, s (timing column).
    """

    agent: str
    scenario: str
    episodes: int
    captured: int
    capture_rate: Estimate
    figures: dict[str, Estimate]
    km_median: Estimate
    survival: SurvivalCurve
    failures: dict[str, int]
    paired: PairedComparison | None
    wall_clock_s_mean: float


def _outcomes(records: Iterable[EpisodeRecord]) -> dict[int, float]:
    return {r.seed: (r.capture_time if r.captured else math.inf) for r in records}


def summarise(
    records: Sequence[EpisodeRecord], reference: Sequence[EpisodeRecord] | None = None
) -> Summary:
    """Summarise the records of one agent on one scenario.

    Args:
        records: that cell's episodes (non-empty, one agent, one scenario).
        reference: the reference agent's episodes on the same scenario, for the paired comparison;
            None to skip it.
    """
    if not records:
        raise ValueError("cannot summarise an empty set of episodes")
    captured = sum(r.captured for r in records)
    figures = {
        stem: bootstrap_estimate([getattr(r, attr) for r in records], stat)
        for stem, attr, stat in ESTIMATED_FIGURES
    }
    survival = kaplan_meier([r.end_time for r in records], [r.captured for r in records])
    return Summary(
        agent=records[0].agent,
        scenario=records[0].scenario,
        episodes=len(records),
        captured=captured,
        capture_rate=wilson_interval(captured, len(records)),
        figures=figures,
        km_median=survival.median(),
        survival=survival,
        failures=dict(Counter(r.failure for r in records if not r.captured)),
        paired=None
        if reference is None
        else paired_comparison(_outcomes(records), _outcomes(reference)),
        wall_clock_s_mean=float(np.mean([r.wall_clock_s for r in records])),
    )


Cell = tuple[list[EpisodeRecord], list[EpisodeRecord] | None]


def summary_cells(
    records: Sequence[EpisodeRecord], reference_agent: str = REFERENCE_AGENT
) -> list[Cell]:
    """What :func:`summarise` takes for each agent x scenario, in the order the cells first
    appear in ``records``: the cell's episodes by seed, and the reference agent's on that
    scenario to pair them with (None for the reference itself, or where it did not play)."""
    cells: dict[tuple[str, str], list[EpisodeRecord]] = {}
    for r in records:
        cells.setdefault((r.agent, r.scenario), []).append(r)
    out: list[Cell] = []
    for (agent, scenario), cell in cells.items():
        ref = cells.get((reference_agent, scenario))
        paired_with = None if agent == reference_agent or ref is None else ref
        out.append((sorted(cell, key=lambda r: r.seed), paired_with))
    return out


def summarise_cells(cells: Sequence[Cell]) -> list[Summary]:
    """:func:`summarise` of each cell of :func:`summary_cells`, in order (each cell's bootstrap
    has its own fixed seed: a cell's summary is the same whichever process makes it)."""
    return [summarise(cell, paired_with) for cell, paired_with in cells]


def summarise_all(
    records: Sequence[EpisodeRecord], reference_agent: str = REFERENCE_AGENT
) -> list[Summary]:
    """One summary per agent x scenario, in the order the cells first appear in ``records``."""
    return summarise_cells(summary_cells(records, reference_agent))


def failure_reasons(summaries: Iterable[Summary]) -> list[str]:
    """The failure columns: the known reasons, then any other reason found, sorted."""
    found = {reason for s in summaries for reason in s.failures}
    return list(KNOWN_FAILURES) + sorted(found - set(KNOWN_FAILURES))


def summary_row(summary: Summary, reasons: Sequence[str]) -> dict[str, Any]:
    """Flatten a summary into one ``results.csv`` row (column order is fixed)."""
    row: dict[str, Any] = {
        "agent": summary.agent,
        "scenario": summary.scenario,
        "episodes": summary.episodes,
        "captured": summary.captured,
    }

    def put(stem: str, est: Estimate) -> None:
        row[stem], row[f"{stem}_low"], row[f"{stem}_high"] = est.value, est.low, est.high

    put("capture_rate", summary.capture_rate)
    for stem, _attr, _stat in ESTIMATED_FIGURES[:2]:
        put(stem, summary.figures[stem])
    put("km_median_time", summary.km_median)
    for stem, _attr, _stat in ESTIMATED_FIGURES[2:]:
        put(stem, summary.figures[stem])
    for reason in reasons:
        row[f"failures_{reason}"] = summary.failures.get(reason, 0)
    paired = summary.paired
    nan = math.nan
    row["paired_pairs"] = paired.pairs if paired else 0
    put("prob_improvement", paired.prob_improvement if paired else Estimate(nan))
    put("paired_time_difference", paired.time_difference if paired else Estimate(nan))
    row["paired_both_captured"] = paired.both_captured if paired else 0
    row["paired_only_agent"] = paired.only_agent if paired else 0
    row["paired_only_reference"] = paired.only_reference if paired else 0
    row["paired_neither"] = paired.neither if paired else 0
    row["wall_clock_s_mean"] = summary.wall_clock_s_mean
    return row


RESULT_TIMING_COLUMNS = frozenset({"wall_clock_s_mean"})


@dataclass(frozen=True)
class RankingRow:
    """One agent's line in the overall ranking (``rank`` is None for privileged agents).

    ``mean_relative_speed_median``: the mean over the scenarios with a capture of the median
    relative speed at capture, m/s (NaN if the agent captured nowhere); shown, not ranked.
    """

    agent: str
    rank: int | None
    mean_capture_rate: float
    mean_ratio_median: float
    scenarios: int
    privileged: bool
    mean_relative_speed_median: float = math.nan

    @classmethod
    def from_json(cls, row: dict[str, Any]) -> RankingRow:
        """A row of ``results.json``'s ``ranking`` (where NaN is written as null)."""

        def number(value: Any) -> float:
            return math.nan if value is None else float(value)

        return cls(
            agent=row["agent"],
            rank=row["rank"],
            mean_capture_rate=number(row["mean_capture_rate"]),
            mean_ratio_median=number(row["mean_ratio_median"]),
            scenarios=row["scenarios"],
            privileged=row["privileged"],
            mean_relative_speed_median=number(row["mean_relative_speed_median"]),
        )


def rank_agents(
    summaries: Sequence[Summary], privileged: Iterable[str] = PRIVILEGED_AGENTS
) -> list[RankingRow]:
    """The overall ranking (rule: :data:`RANKING_RULE`); privileged agents last, unranked."""
    privileged = set(privileged)
    by_agent: dict[str, list[Summary]] = {}
    for s in summaries:
        by_agent.setdefault(s.agent, []).append(s)
    rows = []
    for agent, cells in by_agent.items():
        rates = [s.capture_rate.value for s in cells]
        ratios = [s.figures["ratio_median"].value for s in cells]
        ratios = [math.inf if math.isnan(v) else v for v in ratios]
        speeds = [s.figures["relative_speed_at_capture_median"].value for s in cells]
        speeds = [v for v in speeds if not math.isnan(v)]
        rows.append(
            RankingRow(
                agent=agent,
                rank=None,
                mean_capture_rate=float(np.mean(rates)),
                mean_ratio_median=float(np.mean(ratios)),
                scenarios=len(cells),
                privileged=agent in privileged,
                mean_relative_speed_median=float(np.mean(speeds)) if speeds else math.nan,
            )
        )
    rows.sort(
        key=lambda r: (r.privileged, -round(r.mean_capture_rate, 9), r.mean_ratio_median, r.agent)
    )
    ranked, rank = [], 0
    for r in rows:
        if not r.privileged:
            rank += 1
        ranked.append(
            RankingRow(
                r.agent,
                None if r.privileged else rank,
                r.mean_capture_rate,
                r.mean_ratio_median,
                r.scenarios,
                r.privileged,
                r.mean_relative_speed_median,
            )
        )
    return ranked
