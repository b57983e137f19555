"""The learning-curves page's aggregate statistics over training seeds (rliable).

The unit of replication is the training seed: a run's score is the mean per-episode score
(`capture_bench.task.score.episode_score`) of its last validation, the ``mean_score``
column of its ``validations.csv``, so an algorithm's rliable score matrix is (training seeds x 1
scenario). Per algorithm: IQM, optimality gap and mean over its seeds with 95% stratified
bootstrap intervals; between algorithms: rliable's probability of improvement P(X > Y), the chance
that a run of X ends with a higher score than a run of Y (`capture_bench.rliable_stats`,
Agarwal et al. 2021). An algorithm needs two runs with a final ``mean_score`` to have an interval
over seeds; one with fewer is named with the reason instead.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from capture_bench import rliable_stats

TITLE = "Aggregate statistics over training seeds (rliable)"
MIN_SEEDS = 2


def score_matrices(
    final_scores: Mapping[str, Mapping[int, float]],
) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """``({algorithm: (seeds x 1) matrix of final mean scores}, {algorithm: why left out})``
    from ``{algorithm: {training seed: final mean_score (NaN: none)}}``; seeds in increasing
    order."""
    matrices, left_out = {}, {}
    for algo, by_seed in final_scores.items():
        lacking = [seed for seed, value in sorted(by_seed.items()) if not math.isfinite(value)]
        if lacking:
            seeds = ", ".join(map(str, lacking))
            left_out[algo] = f"no mean_score in the validations.csv of seed {seeds}"
        elif len(by_seed) < MIN_SEEDS:
            left_out[algo] = f"{len(by_seed)} training seed; an interval needs {MIN_SEEDS}"
        else:
            matrices[algo] = np.array([[by_seed[s]] for s in sorted(by_seed)], dtype=float)
    return matrices, left_out


def compute(
    final_scores: Mapping[str, Mapping[int, float]],
    reps: int = rliable_stats.REPS,
    seed: int = rliable_stats.SEED,
) -> dict[str, Any]:
    """The statistics (module docstring), JSON-ready: ``algorithms`` (per algorithm its seeds,
    their final scores and each aggregate's value, low and high), ``probability_of_improvement``
    (one entry per pair X before Y in the given order), ``left_out`` and the method."""
    matrices, left_out = score_matrices(final_scores)
    aggregates = rliable_stats.aggregate_estimates(matrices, reps, seed)
    names = list(matrices)
    pairs = [(x, y) for i, x in enumerate(names) for y in names[i + 1 :]]
    improvement = rliable_stats.improvement_probabilities(pairs, matrices, reps, seed)
    profiles = rliable_stats.performance_profiles(matrices, reps=reps, seed=seed)
    return {
        "unit_of_replication": "training seed",
        "score": "mean per-episode score of the run's last validation",
        "interval": (
            f"{rliable_stats.CONFIDENCE:.0%} percentile stratified bootstrap over the training "
            f"seeds, {reps} resamples, numpy seed {seed}"
        ),
        "optimality_gap_gamma": rliable_stats.GAMMA,
        "algorithms": {
            algo: {
                "seeds": sorted(final_scores[algo]),
                "final_scores": matrices[algo][:, 0].tolist(),
                **{k: v.as_dict() for k, v in aggregates[algo].items()},
            }
            for algo in names
        },
        "probability_of_improvement": [
            {"x": x, "y": y, **estimate.as_dict()} for (x, y), estimate in improvement.items()
        ],
        "performance_profiles": {
            algo: {k: getattr(profile, k).tolist() for k in ("taus", "share", "low", "high")}
            for algo, profile in profiles.items()
        },
        "left_out": left_out,
    }


def _format(estimate: Mapping[str, float]) -> str:
    return f"{estimate['value']:.3f} [{estimate['low']:.3f}, {estimate['high']:.3f}]"


def markdown_lines(numbers: Mapping[str, Any]) -> list[str]:
    """The page's section: what each number means, the table per algorithm, P(X > Y)."""
    lines = [
        f"## {TITLE}",
        "",
        "Computed by the rliable package (Agarwal et al. 2021, NeurIPS). The unit of replication "
        "is the training seed: a run's score is the mean per-episode score (physical limit / "
        "capture time for a capture, 0 for a failure) of its last validation; the intervals "
        f"are rliable's {numbers['interval']}. "
        "IQM: the mean of the middle half of the runs' scores (a quarter trimmed from each end; "
        "with three seeds or fewer, the mean). Optimality gap: 1 - mean(min(score, 1)), how far "
        "the runs fall short of the best possible; lower is better. Mean: the runs' mean score. "
        "P(X > Y): rliable's probability of improvement, the chance that a run of X ends with a "
        "higher score than a run of Y (ties 1/2). Few seeds make wide intervals.",
        "",
    ]
    algorithms = numbers["algorithms"]
    if algorithms:
        lines += [
            "| algorithm | seeds | final scores | IQM | optimality gap | mean |",
            "|---|---|---|---|---|---|",
        ]
        for algo, row in algorithms.items():
            scores = ", ".join(f"{v:.3f}" for v in row["final_scores"])
            figures = " | ".join(_format(row[k]) for k in rliable_stats.AGGREGATES)
            lines.append(f"| {algo.upper()} | {len(row['seeds'])} | {scores} | {figures} |")
        lines.append("")
    if numbers["probability_of_improvement"]:
        lines += ["| X | Y | P(X > Y) |", "|---|---|---|"]
        for pair in numbers["probability_of_improvement"]:
            lines.append(f"| {pair['x'].upper()} | {pair['y'].upper()} | {_format(pair)} |")
        lines.append("")
    for algo, reason in numbers["left_out"].items():
        lines += [f"Left out: {algo.upper()}: {reason}.", ""]
    return lines
