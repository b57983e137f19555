"""The report's section "Training seeds": how much a learned row owes to its training seed.

A model shipped from several training seeds (its card's ``seeds``) ships the policy of the
median validation score; the leaderboard's row, its ranks and every paired comparison are that
policy's. The evaluation also plays each other seed's policy on the same scenarios and episode
seeds (the shipped seed's episodes are the row's own). Per agent, each seed's score on a scenario
is the mean per-episode score (`capture_bench.task.score.episode_score`) of its episodes there,
which makes an rliable score matrix of (training seeds x scenarios); its IQM carries the 95%
stratified-bootstrap interval over the seeds (`capture_bench.rliable_stats`, as the learning
curves' statistics over training seeds, `capture_bench.training.curves.seed_statistics`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from capture_bench import rliable_stats
from capture_bench.evaluation.reporting.summary import score
from capture_bench.evaluation.running.rollout import EpisodeRecord

TITLE = "Training seeds"
#: The section's key in ``results.json``, and the key of a seeded agent's IQM on its ranking row.
KEY = "training_seeds"
RANKING_KEY = "training_seeds_iqm"
#: The ranking table's column of a report with seeded agents.
COLUMN = "seed IQM [95% CI]"
#: What the report says, by its paired comparisons, of the policy a learned row plays.
ROW_POLICY = (
    "Learned rows: the shipped policy (median of its training seeds); the other seeds are in "
    f'"{TITLE}".'
)
HEADER = ("agent", "training seeds", "shipped", "per-seed score", COLUMN)


@dataclass(frozen=True)
class SeedScores:
    """One agent's scores over its training seeds.

    Attributes:
        seeds: the training seeds, increasing (the matrix's rows).
        shipped: the seed whose policy the leaderboard's row plays.
        scenarios: the matrix's columns.
        scores: (seeds x scenarios) mean per-episode score of each seed on each scenario.
        iqm: rliable's IQM of ``scores`` with its 95% stratified-bootstrap interval.
        reps, seed: the bootstrap's resamples and numpy seed.
    """

    seeds: list[int]
    shipped: int
    scenarios: list[str]
    scores: np.ndarray
    iqm: rliable_stats.IntervalEstimate
    reps: int
    seed: int

    def per_seed(self) -> list[float]:
        """Each seed's mean over the scenarios of its scores."""
        return [float(v) for v in self.scores.mean(axis=1)]


def compute(
    records_by_seed: Mapping[int, Sequence[EpisodeRecord]],
    shipped: int,
    reps: int = rliable_stats.REPS,
    seed: int = rliable_stats.SEED,
) -> SeedScores:
    """The `SeedScores` of one agent from each training seed's records ({seed: its episodes};
    the shipped seed's are the row's); the scenarios in the order they first appear in the
    shipped seed's records.

    Raises:
        ValueError: a seed without an episode on one of the scenarios.
    """
    seeds = sorted(records_by_seed)
    scenarios = list(dict.fromkeys(r.scenario for r in records_by_seed[shipped]))
    rows = []
    for s in seeds:
        by_scenario: dict[str, list[float]] = {}
        for r in records_by_seed[s]:
            by_scenario.setdefault(r.scenario, []).append(score(r))
        if any(not by_scenario.get(name) for name in scenarios):
            raise ValueError(f"training seed {s} has no episode on some of {scenarios}")
        rows.append([float(np.mean(by_scenario[name])) for name in scenarios])
    matrix = np.array(rows, dtype=float)
    estimate = rliable_stats.aggregate_estimates({"seeds": matrix}, reps, seed)["seeds"]["iqm"]
    return SeedScores(seeds, shipped, scenarios, matrix, estimate, reps, seed)


def fmt(estimate: rliable_stats.IntervalEstimate) -> str:
    """``value [low, high]``, three decimals."""
    return f"{estimate.value:.3f} [{estimate.low:.3f}, {estimate.high:.3f}]"


def ranking_cell(seeds: Mapping[str, SeedScores], agent: str) -> str:
    """The ranking table's `COLUMN` for ``agent``: its seed IQM with the interval, a dash for
    an agent without training seeds."""
    return fmt(seeds[agent].iqm) if agent in seeds else "—"


def text(seeds: Mapping[str, SeedScores]) -> str:
    """What the section's numbers are."""
    first = next(iter(seeds.values()))
    return (
        "A learned row is the policy its model ships: of the training seeds it was trained with, "
        "the one of the median validation score (validation seeds, never a published one; "
        "named in its model card). Its rank and every paired comparison are that policy's. "
        "Each other seed's policy played the same scenarios and episode seeds. A seed's score "
        "on a scenario is the mean of its episodes' scores (physical limit / capture time for a "
        "capture, 0 for a failure); the per-seed score is its mean over the scenarios. The seed "
        "IQM is rliable's IQM of the (training seeds x scenarios) matrix (with three seeds or "
        "fewer on one scenario, their mean), its interval the 95% stratified bootstrap over the "
        f"seeds within each scenario ({first.reps} resamples, numpy seed {first.seed}); few "
        "seeds make wide intervals. The IQM leaves out the quarter of lowest and the quarter of "
        "highest (seed, scenario) scores, a hard scenario's among them, so it may lie above "
        "every seed's mean over the scenarios."
    )


def rows(seeds: Mapping[str, SeedScores]) -> list[list[str]]:
    """The section's table: per agent its seeds, the shipped one, each seed's score, the IQM."""
    return [
        [
            agent,
            ", ".join(map(str, s.seeds)),
            str(s.shipped),
            ", ".join(f"{seed}: {v:.3f}" for seed, v in zip(s.seeds, s.per_seed())),
            fmt(s.iqm),
        ]
        for agent, s in seeds.items()
    ]


def payload(seeds: Mapping[str, SeedScores]) -> dict[str, Any]:
    """The section in ``results.json``: the method, and per agent its seeds, the shipped one,
    the (seeds x scenarios) scores, each seed's mean and the IQM with its interval."""
    first = next(iter(seeds.values()))
    return {
        "unit_of_replication": "training seed, stratified by scenario",
        "score": "mean per-episode score of the seed's episodes on a scenario",
        "interval": (
            f"{rliable_stats.CONFIDENCE:.0%} percentile stratified bootstrap, "
            f"{first.reps} resamples, numpy seed {first.seed}"
        ),
        "row_policy": "the shipped policy (median validation score of its training seeds)",
        "agents": {
            agent: {
                "seeds": s.seeds,
                "shipped": s.shipped,
                "scenarios": s.scenarios,
                "scores": s.scores.tolist(),
                "per_seed": dict(zip(map(str, s.seeds), s.per_seed())),
                "iqm": s.iqm.as_dict(),
            }
            for agent, s in seeds.items()
        },
    }
