"""The report's summary, taken in at a glance: what the ranking plot (under the ranking's
table), the heatmap and the probability-of-improvement matrix (of the best-ranked agents:
`capture_bench.evaluation.reporting.plots.improvement_agents`) near the top of the HTML show, as
numbers.

* **heatmap**: agent x scenario, the capture rate and the median ratio to the physical limit of
  each cell (the same `Summary` figures as the
  tables);
* **ranking with intervals**: each agent's mean capture rate over the ranked scenarios (the
  ranking's number) with a 95% percentile-bootstrap interval, resampling the published seeds
  within each scenario, the same resample for every agent (paired), beside its 95% rank interval
  and its tie group (`capture_bench.evaluation.reporting.aggregate.with_rank_intervals`: an agent is
  tied with the agent ranked just above it when their rank intervals overlap);
* **probability of improvement** P(X > Y), rliable's definition (Agarwal et al. 2021): per
  scenario, the Mann-Whitney U statistic of X's episode scores against Y's over n * m (ties count
  1/2: `mann_whitney_u`, ``scipy.stats.mannwhitneyu``'s statistic), averaged over
  scenarios. An episode's score (`capture_bench.task.score.episode_score`) is physical
  limit / capture time, in (0, 1], and 0 for a failure, so a capture beats a failure and a
  faster capture a slower one. rliable's own statistics of the same scores, with intervals, are
  a section of the report (`capture_bench.evaluation.reporting.rliable_report`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from capture_bench.evaluation.reporting.aggregate import RankingRow, Summary, counted_scenarios
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.task.score import episode_score

BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0


@dataclass(frozen=True)
class RankedInterval:
    """One ranked agent: the mean capture rate over the ranked scenarios and its 95% interval;
    whether it is tied with the agent ranked just above it (None for the first); its ranking row
    (rank, rank interval, tie group)."""

    agent: str
    mean_capture_rate: float
    low: float
    high: float
    tied_with_previous: bool | None
    row: RankingRow


def _by_cell(records: Sequence[EpisodeRecord]) -> dict[tuple[str, str], dict[int, EpisodeRecord]]:
    cells: dict[tuple[str, str], dict[int, EpisodeRecord]] = {}
    for r in records:
        cells.setdefault((r.agent, r.scenario), {})[r.seed] = r
    return cells


def score(record: EpisodeRecord) -> float:
    """The episode's score (`capture_bench.task.score.episode_score`): physical limit /
    capture time for a capture with a finite positive bound (1 where the bound is not finite: a
    capture the bound says is impossible counts as fastest), 0 for a failure."""
    return episode_score(record.outcome == "captured", record.ratio)


def ranking_intervals(
    records: Sequence[EpisodeRecord], ranking: Sequence[RankingRow]
) -> list[RankedInterval]:
    """The ranked (not privileged) agents, in ranking order, with bootstrap intervals of their
    mean capture rate over the scenarios the ranking counts (its rows' ``unranked`` left out),
    and their tie groups (module docstring)."""
    ranked = sorted((r for r in ranking if r.rank is not None), key=lambda r: r.rank or 0)
    left_out = {name for r in ranking for name in r.unranked}
    cells = _by_cell(records)
    scenarios = sorted(counted_scenarios((s for (_, s) in cells), left_out))
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    # captured[agent] -> per scenario an array over that scenario's seeds (sorted)
    captured: dict[str, list[np.ndarray]] = {r.agent: [] for r in ranked}
    draws = []
    for scenario in scenarios:
        # every seed any agent played here; a seed an agent did not play counts as a failure
        seeds = sorted({seed for a in captured for seed in cells.get((a, scenario), {})})
        for agent in captured:
            row = cells.get((agent, scenario), {})
            played = [s in row and row[s].outcome == "captured" for s in seeds]
            captured[agent].append(np.array(played, float))
        draws.append(rng.integers(0, len(seeds), (BOOTSTRAP_RESAMPLES, len(seeds))))
    out = []
    for i, line in enumerate(ranked):
        per = [c for c in captured[line.agent] if c.size]
        mean = float(np.mean([c.mean() for c in per])) if per else math.nan
        boot = [c[d].mean(axis=1) for c, d in zip(captured[line.agent], draws) if c.size]
        low, high = np.percentile(np.mean(boot, axis=0), [2.5, 97.5]) if boot else (mean, mean)
        tied = None if i == 0 else bool(line.tied and line.tie_first != line.rank)
        out.append(RankedInterval(line.agent, mean, float(low), float(high), tied, line))
    return out


def probability_of_improvement(
    records: Sequence[EpisodeRecord], agents: Sequence[str]
) -> np.ndarray:
    """P[i, j] = P(agents[i] > agents[j]) (module docstring); the diagonal is 1/2."""
    cells = _by_cell(records)
    scenarios = sorted({s for (_, s) in cells})
    scores = {
        (agent, scenario): np.array([score(r) for r in cells.get((agent, scenario), {}).values()])
        for agent in agents
        for scenario in scenarios
    }
    n = len(agents)
    out = np.full((n, n), 0.5)
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            values = []
            for scenario in scenarios:
                x, y = scores[agents[i], scenario], scores[agents[j], scenario]
                if x.size and y.size:
                    values.append(mann_whitney_u(x, y) / (x.size * y.size))
            out[i, j] = float(np.mean(values)) if values else math.nan
    return out


def mann_whitney_u(x: np.ndarray, y: np.ndarray) -> float:
    """The Mann-Whitney U statistic of ``x`` against ``y``: the pairs (a in x, b in y) with
    a > b, ties counting 1/2. Exactly ``scipy.stats.mannwhitneyu(x, y).statistic`` (a sum of
    halves, exact in floating point either way; tested), counted pair by pair in one array
    operation instead of through ranks."""
    above = x[:, None] > y[None, :]
    ties = x[:, None] == y[None, :]
    return float(np.count_nonzero(above)) + 0.5 * float(np.count_nonzero(ties))


def heatmap_cells(
    summaries: Sequence[Summary], agents: Sequence[str], scenarios: Sequence[str]
) -> tuple[np.ndarray, np.ndarray]:
    """(capture rate, median ratio to the limit) per agent x scenario; NaN where absent."""
    rate = np.full((len(agents), len(scenarios)), math.nan)
    ratio = np.full_like(rate, math.nan)
    index = {(s.agent, s.scenario): s for s in summaries}
    for i, agent in enumerate(agents):
        for j, scenario in enumerate(scenarios):
            s = index.get((agent, scenario))
            if s is not None:
                rate[i, j] = s.capture_rate.value
                ratio[i, j] = s.figures["ratio_median"].value
    return rate, ratio
