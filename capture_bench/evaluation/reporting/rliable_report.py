"""The report's section "Aggregate statistics (rliable)": each agent's per-episode scores as
rliable score matrices, and their IQM, optimality gap, mean, performance profile and probability
of improvement over the reference (`capture_bench.rliable_stats`, Agarwal et al. 2021).

The unit of replication is the episode: the leaderboard evaluates one model per agent, so an
agent's score matrix has one row per published seed and one column per scenario (episodes x
scenarios; row i holds the i-th seed, in increasing order, of each scenario), and the bootstrap
resamples the seeds within each scenario (stratified by scenario). rliable's matrix is
rectangular, so the section needs every agent to have played every scenario of the report on
the same number of seeds in each; where that does not hold it says why instead of the table.
An episode's score is `capture_bench.task.score.episode_score`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from capture_bench import rliable_stats
from capture_bench.evaluation.reporting.summary import score
from capture_bench.evaluation.running.rollout import EpisodeRecord

TITLE = "Aggregate statistics (rliable)"
#: The section's key in ``results.json``.
KEY = "rliable"
FIGURE = "performance_profile.png"
HEADER = (
    "agent",
    "IQM",
    "optimality gap",
    "mean",
    "P(agent > reference)",
)


@dataclass(frozen=True)
class RliableSection:
    """The section's numbers.

    Attributes:
        agents: the agents, in the report's order.
        scenarios: the matrices' columns, in order.
        episodes: episodes per scenario of each agent (the matrix's rows).
        reference: the agent P(agent > reference) compares with; None if the report lacks it.
        aggregates: agent -> {"iqm", "optimality_gap", "mean"} -> estimate with its interval.
        improvement: agent -> P(agent > reference) with its interval (the reference has none).
        reps, seed: the bootstrap's resamples and numpy seed.
    """

    agents: list[str]
    scenarios: list[str]
    episodes: dict[str, int]
    reference: str | None
    aggregates: dict[str, dict[str, rliable_stats.IntervalEstimate]]
    improvement: dict[str, rliable_stats.IntervalEstimate]
    reps: int
    seed: int


def score_matrices(
    records: Sequence[EpisodeRecord], agents: Sequence[str] | None = None
) -> tuple[dict[str, np.ndarray], list[str]]:
    """``({agent: (episodes x scenarios) score matrix}, scenarios)``: row i of a matrix holds
    the agent's i-th seed (increasing) of each scenario; the scenarios in the order they first
    appear in ``records``, the agents in ``agents``' order (default: as they first appear).

    Raises:
        ValueError: an agent has no episode on some scenario, or not the same number on every
            scenario (the message names them).
    """
    scenarios = list(dict.fromkeys(r.scenario for r in records))
    order = list(dict.fromkeys(r.agent for r in records)) if agents is None else list(agents)
    cells: dict[tuple[str, str], dict[int, float]] = {}
    for r in records:
        cells.setdefault((r.agent, r.scenario), {})[r.seed] = score(r)
    matrices = {}
    for agent in order:
        columns = []
        for scenario in scenarios:
            cell = cells.get((agent, scenario))
            if not cell:
                raise ValueError(f"{agent} has no episode on {scenario}")
            columns.append([cell[seed] for seed in sorted(cell)])
        counts = {scenario: len(c) for scenario, c in zip(scenarios, columns)}
        if len(set(counts.values())) > 1:
            played = ", ".join(f"{n} on {s}" for s, n in counts.items())
            raise ValueError(f"{agent} played {played}")
        matrices[agent] = np.array(columns, dtype=float).T
    return matrices, scenarios


def unavailable(records: Sequence[EpisodeRecord], agents: Sequence[str]) -> str | None:
    """Why the section cannot be computed for these records (None if it can)."""
    if not records:
        return "no episode"
    try:
        score_matrices(records, agents)
    except ValueError as exc:
        return (
            "every agent must play every scenario on the same number of seeds (rliable's score "
            f"matrix is episodes x scenarios); here {exc}"
        )
    return None


def compute(
    records: Sequence[EpisodeRecord],
    agents: Sequence[str],
    reference: str,
    reps: int = rliable_stats.REPS,
    seed: int = rliable_stats.SEED,
) -> RliableSection:
    """The section's numbers (module docstring); ``reps`` resamples of numpy seed ``seed``.

    Raises:
        ValueError: the records do not make rectangular matrices (`unavailable`).
        rliable_stats.RliableMissing: rliable is not installed.
    """
    matrices, scenarios = score_matrices(records, agents)
    aggregates = rliable_stats.aggregate_estimates(matrices, reps, seed)
    ref = reference if reference in matrices else None
    pairs = [(agent, reference) for agent in matrices if ref is not None and agent != ref]
    improvement = rliable_stats.improvement_probabilities(pairs, matrices, reps, seed)
    return RliableSection(
        agents=list(matrices),
        scenarios=scenarios,
        episodes={agent: int(m.shape[0]) for agent, m in matrices.items()},
        reference=ref,
        aggregates=aggregates,
        improvement={x: estimate for (x, _), estimate in improvement.items()},
        reps=reps,
        seed=seed,
    )


def profiles(
    records: Sequence[EpisodeRecord],
    agents: Sequence[str],
    reps: int = rliable_stats.REPS,
    seed: int = rliable_stats.SEED,
) -> dict[str, rliable_stats.Profile]:
    """Each agent's performance profile over its episodes x scenarios scores."""
    matrices, _ = score_matrices(records, agents)
    return rliable_stats.performance_profiles(matrices, reps=reps, seed=seed)


def text(section: RliableSection) -> str:
    """What each number means, and the unit of replication."""
    counts = sorted(set(section.episodes.values()))
    seeds = " or ".join(map(str, counts))
    reference = section.reference or "the reference agent"
    return (
        "Computed by the rliable package (Agarwal et al. 2021, NeurIPS) from each episode's "
        "score: physical limit / capture time for a capture (1 = as fast as physically possible), "
        "0 for a failure. The unit of replication is the episode: the leaderboard evaluates one "
        f"model per agent, so an agent's score matrix holds its {seeds} seeds (rows) of "
        f"each of the {len(section.scenarios)} scenarios (columns), and the 95% intervals are "
        "rliable's stratified bootstrap, the seeds resampled within each scenario "
        f"({section.reps} resamples, numpy seed {section.seed}). IQM: the mean of the middle half "
        "of the agent's episode scores over every scenario (a quarter trimmed from each end), "
        "robust to a few outlying episodes. Optimality gap: how far the scores fall short of the "
        "best possible, 1 - mean(min(score, 1)); lower is better, and with scores at most 1 it "
        "is 1 - the mean. Mean: the mean score over scenarios, each weighing the same. "
        f"P(agent > reference): rliable's probability of improvement over {reference}, the chance "
        "that an episode of the agent scores higher than an episode of the reference on the same "
        "scenario (ties 1/2), averaged over scenarios; its value is the summary matrix's, and "
        "its interval is per comparison (each agent against the reference alone), not corrected "
        "for multiple comparisons. The "
        f"performance profile ({FIGURE}) draws, for each score threshold tau in [0, 1], the "
        "share of the agent's episodes scoring above tau, with 95% bands."
    )


def cells(section: RliableSection, agent: str, label: str) -> list[str]:
    """One table row: ``label``, then IQM, optimality gap, mean, P(agent > reference), each
    ``value [low, high]``."""
    figures = section.aggregates[agent]
    improvement = section.improvement.get(agent)
    return [
        label,
        *(_format(figures[name]) for name in rliable_stats.AGGREGATES),
        "—" if improvement is None else _format(improvement),
    ]


def _format(estimate: rliable_stats.IntervalEstimate) -> str:
    return f"{estimate.value:.3f} [{estimate.low:.3f}, {estimate.high:.3f}]"


def payload(section: RliableSection | None, reason: str | None) -> dict[str, Any]:
    """The section in ``results.json``: the method, and each agent's figures (or why not)."""
    if section is None:
        return {"left_out": reason}
    return {
        "library": "rliable",
        "citation": rliable_stats.CITATION,
        "score": "physical limit / capture time for a capture, 0 for a failure",
        "unit_of_replication": "episode (published seed), stratified by scenario",
        "scenarios": section.scenarios,
        "interval": (
            f"{rliable_stats.CONFIDENCE:.0%} percentile stratified bootstrap, "
            f"{section.reps} resamples, numpy seed {section.seed}"
        ),
        "optimality_gap_gamma": rliable_stats.GAMMA,
        "reference": section.reference,
        "agents": [
            {
                "agent": agent,
                "episodes_per_scenario": section.episodes[agent],
                **{k: v.as_dict() for k, v in section.aggregates[agent].items()},
                "probability_of_improvement_over_reference": (
                    section.improvement[agent].as_dict() if agent in section.improvement else None
                ),
            }
            for agent in section.agents
        ],
    }
