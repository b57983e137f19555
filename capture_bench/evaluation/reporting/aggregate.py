"""Episode records -> one summary per agent x scenario, and the overall ranking.

Pure functions of the records (see `capture_bench.evaluation.reporting.metrics` for the statistics).

Ranking rule (`RANKING_RULE`): agents are ranked by their capture rate averaged over the
suite's scenarios (each scenario weighs the same); ties (equal to 1e-9) are broken by the mean over
scenarios of the median ratio to the physical limit (lower first; a scenario with no capture counts
as +inf), then by name. Privileged agents (the ``oracle``, which reads the true trajectory) are
listed as references and not ranked.

A scenario whose file says ``ranked: false`` (`unranked_scenarios`) counts in none of the
ranking's averages; the report shows it in its own table. Where every scenario evaluated is
unranked, the ranking is over all of them (`counted_scenarios`).

Each ranked agent's rank has a 95% interval (`with_rank_intervals`): the seeds of each
counted scenario are resampled with replacement, the same resample for every agent (paired), the
ranking rule is applied to every resample (agents level on both of its numbers sharing the ranks
they span: the name, its last key, says nothing of them), and the interval runs from the 2.5th
percentile of the agent's rank over the resamples to the 97.5th. An agent whose interval overlaps
the interval of the agent ranked just above it is tied with it; a chain of such agents is a tie
group (`tie_groups`).

Beside the ranking (not part of it), each row shows the mean over scenarios of the median
relative speed at capture, so that a controller that flies through the tolerance box instead of
arriving is visible where the ranking is read.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from capture_bench.evaluation.reporting.metrics import (
    Estimate,
    PairedComparison,
    SurvivalCurve,
    bootstrap_estimate,
    kaplan_meier,
    paired_comparison,
    wilson_interval,
)
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.task.scenarios import ConfigError, Scenario, load_scenario
from capture_bench.task.step_rule import FAILURES

REFERENCE_AGENT = "incremental_ik"
PRIVILEGED_AGENTS = frozenset({"oracle"})
#: Failure reasons always given a column, in this order; others found are appended sorted.
KNOWN_FAILURES = FAILURES  # the step rule's, in its order
#: Resamples and numpy seed of the rank intervals' bootstrap.
RANK_RESAMPLES = 2000
RANK_SEED = 0
#: The rank interval's percentiles.
RANK_PERCENTILES = (2.5, 97.5)
RANKING_RULE = (
    "Ranked by capture rate averaged over scenarios (equal weights); ties broken by the mean over "
    "scenarios of the median capture-time ratio to the physical limit (lower is better, a scenario "
    "with no capture counts as +inf), then by name. Privileged agents (oracle) are references, "
    "not ranked. The median relative speed at capture (mean over the scenarios with a capture) "
    "is shown, not ranked: a fly-through of the tolerance box is fast, an arrival slow. "
    "Scenarios marked ranked: false count in none of these averages (where every scenario "
    "evaluated is so marked, the ranking is over them all). Rank interval (95%): the seeds of "
    "each scenario are resampled with replacement, the same seeds for every agent (paired "
    f"bootstrap, {RANK_RESAMPLES} resamples, fixed seed), the agents are ranked by this rule in "
    "each resample (agents level on both numbers share the ranks they span), and the interval "
    "runs from the 2.5th percentile of the agent's rank to the 97.5th. Tie groups: an agent "
    "whose rank interval overlaps that of the agent ranked just above it is tied with it, and a "
    "chain of such agents is one tie group."
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
        figures: column stem -> bootstrap estimate (see `ESTIMATED_FIGURES`).
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
    """What `summarise` takes for each agent x scenario, in the order the cells first
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
    """`summarise` of each cell of `summary_cells`, in order (each cell's bootstrap
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

    Attributes:
        agent, rank: the agent and its rank (1 the best).
        mean_capture_rate, mean_ratio_median: the ranking's two numbers (`RANKING_RULE`),
            over the scenarios counted (``scenarios`` of them).
        privileged: a reference, not ranked.
        mean_relative_speed_median: the mean over the counted scenarios with a capture of the
            median relative speed at capture, m/s (NaN if the agent captured nowhere); shown, not
            ranked.
        rank_low, rank_high: the 95% rank interval (`with_rank_intervals`); None for a
            privileged agent, or where it was not computed.
        tie_first, tie_last: the ranks of the first and the last agent of the agent's tie group
            (both its own rank when it is tied with no one); None where ``rank_low`` is.
        unranked: the scenarios of the evaluation that count in no average (``ranked: false``).
    """

    agent: str
    rank: int | None
    mean_capture_rate: float
    mean_ratio_median: float
    scenarios: int
    privileged: bool
    mean_relative_speed_median: float = math.nan
    rank_low: int | None = None
    rank_high: int | None = None
    tie_first: int | None = None
    tie_last: int | None = None
    unranked: tuple[str, ...] = ()

    @property
    def tied(self) -> bool:
        """Whether the agent's tie group holds another agent."""
        return self.tie_first is not None and self.tie_first != self.tie_last

    @classmethod
    def from_json(cls, row: dict[str, Any]) -> RankingRow:
        """A row of ``results.json``'s ``ranking`` (where NaN is written as null); the keys a
        report written before the rank intervals lacks take their defaults."""

        def number(value: Any) -> float:
            return math.nan if value is None else float(value)

        def whole(key: str) -> int | None:
            value = row.get(key)
            return None if value is None else int(value)

        return cls(
            agent=row["agent"],
            rank=row["rank"],
            mean_capture_rate=number(row["mean_capture_rate"]),
            mean_ratio_median=number(row["mean_ratio_median"]),
            scenarios=row["scenarios"],
            privileged=row["privileged"],
            mean_relative_speed_median=number(row.get("mean_relative_speed_median")),
            rank_low=whole("rank_low"),
            rank_high=whole("rank_high"),
            tie_first=whole("tie_first"),
            tie_last=whole("tie_last"),
            unranked=tuple(row.get("unranked") or ()),
        )


def unranked_scenarios(
    names: Iterable[str], load: Callable[[str], Scenario] = load_scenario
) -> tuple[str, ...]:
    """The names among ``names`` (in their order, each once) whose scenario says
    ``ranked: false``. A name ``load`` cannot load (a scenario file given by a path, under a name
    no shipped scenario has) counts as ranked."""
    out = []
    for name in dict.fromkeys(names):
        try:
            ranked = load(name).ranked
        except ConfigError:
            continue
        if not ranked:
            out.append(name)
    return tuple(out)


def counted_scenarios(scenarios: Iterable[str], unranked: Collection[str]) -> list[str]:
    """The scenarios the ranking averages over, in their order: those of ``scenarios`` not in
    ``unranked``, or every one of them where each is unranked."""
    names = list(dict.fromkeys(scenarios))
    return [n for n in names if n not in unranked] or names


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if values else math.nan


def _rate_key(rate: float) -> float:
    """The ranking's first key: the mean capture rate to 1e-9, higher first; none last."""
    return math.inf if math.isnan(rate) else -round(rate, 9)


def rank_agents(
    summaries: Sequence[Summary],
    privileged: Iterable[str] = PRIVILEGED_AGENTS,
    records: Sequence[EpisodeRecord] | None = None,
    unranked: Collection[str] | None = None,
) -> list[RankingRow]:
    """The overall ranking (rule: `RANKING_RULE`); privileged agents last, unranked.

    Args:
        summaries: one per agent x scenario.
        privileged: the agents listed as references, not ranked.
        records: the episodes summarised, for the rank intervals (`with_rank_intervals`);
            None to leave them out (the report computes them from its records).
        unranked: the scenarios that count in no average; None for
            `unranked_scenarios` of the summaries' scenarios.
    """
    privileged = set(privileged)
    names = list(dict.fromkeys(s.scenario for s in summaries))
    if unranked is None:
        unranked = unranked_scenarios(names)
    counted = counted_scenarios(names, set(unranked))
    left_out = tuple(n for n in names if n not in counted)
    by_agent: dict[str, list[Summary]] = {}
    for s in summaries:
        cells = by_agent.setdefault(s.agent, [])
        if s.scenario in counted:
            cells.append(s)
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
                mean_capture_rate=_mean(rates),
                mean_ratio_median=_mean(ratios),
                scenarios=len(cells),
                privileged=agent in privileged,
                mean_relative_speed_median=_mean(speeds),
                unranked=left_out,
            )
        )
    rows.sort(
        key=lambda r: (r.privileged, _rate_key(r.mean_capture_rate), r.mean_ratio_median, r.agent)
    )
    ranked, rank = [], 0
    for r in rows:
        if not r.privileged:
            rank += 1
        ranked.append(replace(r, rank=None if r.privileged else rank))
    if records is not None:
        return with_rank_intervals(ranked, records)
    return ranked


def with_rank_intervals(
    ranking: Sequence[RankingRow],
    records: Sequence[EpisodeRecord],
    resamples: int = RANK_RESAMPLES,
    seed: int = RANK_SEED,
) -> list[RankingRow]:
    """``ranking`` (`rank_agents`) with each ranked agent's 95% rank interval and tie group
    (module docstring), from the episodes it ranks.

    The scenarios counted are the ranking's (its rows' ``unranked`` left out), each scenario's
    seeds every seed a ranked agent played there, resampled with a numpy generator seeded with
    ``seed``, scenarios in name order. The interval's low end is the first percentile of
    `RANK_PERCENTILES` of the agent's best rank over the resamples, its high end the second
    of its worst (`ranks_under_weights`; numpy's ``inverted_cdf``: ranks that occurred),
    widened where needed to hold the agent's rank in ``ranking``.
    """
    ranked = sorted((r for r in ranking if r.rank is not None), key=lambda r: r.rank or 0)
    if not ranked:
        return list(ranking)
    left_out = {name for r in ranking for name in r.unranked}
    scenarios = sorted(counted_scenarios((r.scenario for r in records), left_out))
    agents = [r.agent for r in ranked]
    weights = seed_weights(records, agents, scenarios, resamples, seed)
    best, worst = ranks_under_weights(records, agents, weights)
    lows = np.percentile(best, RANK_PERCENTILES[0], axis=0, method="inverted_cdf")
    highs = np.percentile(worst, RANK_PERCENTILES[1], axis=0, method="inverted_cdf")
    intervals = [
        (min(int(low), row.rank or 0), max(int(high), row.rank or 0))
        for low, high, row in zip(lows, highs, ranked)
    ]
    found = {
        row.agent: replace(row, rank_low=low, rank_high=high, tie_first=first, tie_last=last)
        for row, (low, high), (first, last) in zip(ranked, intervals, tie_groups(intervals))
    }
    return [found.get(r.agent, r) for r in ranking]


def tie_groups(intervals: Sequence[tuple[int, int]]) -> list[tuple[int, int]]:
    """The tie group of each of ``intervals`` (the rank intervals of ranks 1, 2, ... in order), as
    the ranks of its first and last agents: an agent whose interval overlaps the interval of the
    agent ranked just above it (its low end at most that one's high end) is in that agent's
    group."""
    starts = [k == 0 or low > intervals[k - 1][1] for k, (low, _high) in enumerate(intervals)]
    groups: list[tuple[int, int]] = []
    for k, start in enumerate(starts):
        if start:
            end = next((j for j in range(k + 1, len(starts)) if starts[j]), len(starts))
            groups += [(k + 1, end)] * (end - k)
    return groups


#: One scenario's resamples: its seeds (sorted), and how many times each seed is drawn in each
#: resample, an array (resamples, seeds).
SeedWeights = dict[str, tuple[list[int], np.ndarray]]


def seed_weights(
    records: Sequence[EpisodeRecord],
    agents: Collection[str],
    scenarios: Sequence[str],
    resamples: int,
    seed: int,
) -> SeedWeights:
    """The paired bootstrap's resamples: for each of ``scenarios`` in turn, its seeds (every seed
    one of ``agents`` played there) drawn with replacement, as many as there are, ``resamples``
    times, from one numpy generator seeded with ``seed``."""
    rng = np.random.default_rng(seed)
    played: dict[str, set[int]] = {s: set() for s in scenarios}
    for r in records:
        if r.agent in agents and r.scenario in played:
            played[r.scenario].add(r.seed)
    out: SeedWeights = {}
    for scenario in scenarios:
        seeds = sorted(played[scenario])
        n = len(seeds)
        if not n:
            continue
        draws = rng.integers(0, n, (resamples, n)) + n * np.arange(resamples)[:, None]
        counts = np.bincount(draws.ravel(), minlength=resamples * n).reshape(resamples, n)
        out[scenario] = (seeds, counts.astype(float))
    return out


def ranks_under_weights(
    records: Sequence[EpisodeRecord], agents: Sequence[str], weights: SeedWeights
) -> tuple[np.ndarray, np.ndarray]:
    """Each agent's best and worst rank (1 the best) by the ranking rule (`RANKING_RULE`)
    in each resample, two arrays (resamples, agents). The two differ where agents are level (the
    same mean capture rate to 1e-9 and the same mean median ratio): the rule's last key, the
    name, says nothing of the agents, so level agents share the ranks they span.

    A resample of a scenario counts each of its seeds as many times as ``weights`` says; an
    agent's capture rate there is over the seeds it played, its median ratio over those captured
    with a finite ratio (+inf where none is), and its means are over the scenarios of
    ``weights`` it played some resampled seed of."""
    index = {a: k for k, a in enumerate(agents)}
    cells: dict[tuple[str, str], dict[int, EpisodeRecord]] = {}
    for r in records:
        if r.agent in index and r.scenario in weights:
            cells.setdefault((r.agent, r.scenario), {})[r.seed] = r
    resamples = next(iter(weights.values()))[1].shape[0] if weights else 1
    shape = (resamples, len(agents))
    rate_sum, ratio_sum, counted = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    for scenario, (seeds, w) in weights.items():
        for agent, k in index.items():
            cell = cells.get((agent, scenario))
            if not cell:
                continue
            played = np.array([s in cell for s in seeds], float)
            captured = np.array([s in cell and cell[s].captured for s in seeds], float)
            plays = w @ played
            some = plays > 0
            rate_sum[some, k] += (w @ captured)[some] / plays[some]
            ratio_sum[some, k] += _weighted_median(cell, seeds, w)[some]
            counted[some, k] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        rate, ratio = rate_sum / counted, ratio_sum / counted
    rate_key = np.where(np.isnan(rate), math.inf, -np.round(rate, 9))[:, :, None]
    ratio = np.where(np.isnan(ratio), math.inf, ratio)[:, :, None]
    other_rate, other_ratio = rate_key.transpose(0, 2, 1), ratio.transpose(0, 2, 1)
    same_rate = other_rate == rate_key
    better = (other_rate < rate_key) | (same_rate & (other_ratio < ratio))
    level = same_rate & (other_ratio == ratio)  # each agent is level with itself
    best = 1 + better.sum(axis=2)
    return best, best + level.sum(axis=2) - 1


def _weighted_median(cell: dict[int, EpisodeRecord], seeds: list[int], w: np.ndarray) -> np.ndarray:
    """Per resample, ``np.median`` of the finite ratios of the captured episodes of ``cell``,
    each seed's counted as many times as ``w`` draws it; +inf where there is none."""
    found = sorted(
        (cell[s].ratio, j)
        for j, s in enumerate(seeds)
        if s in cell and cell[s].captured and math.isfinite(cell[s].ratio)
    )
    if not found:
        return np.full(w.shape[0], math.inf)
    values = np.array([v for v, _ in found])
    cumulative = np.cumsum(w[:, [j for _, j in found]], axis=1)
    total = cumulative[:, -1]
    last = len(values) - 1

    def order_statistic(position: np.ndarray) -> np.ndarray:  # 0-based, of the drawn values
        return values[np.minimum((cumulative <= position[:, None]).sum(axis=1), last)]

    median = 0.5 * (order_statistic((total - 1) // 2) + order_statistic(total // 2))
    return np.where(total > 0, median, math.inf)
