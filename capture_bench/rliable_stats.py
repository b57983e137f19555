"""Aggregate statistics of score matrices, computed by the ``rliable`` package (Agarwal et al.
2021, "Deep Reinforcement Learning at the Edge of the Statistical Precipice", NeurIPS).

The one module that imports rliable, lazily (`require`): the evaluation report and the
learning curves both call it, so it sits below both. A score matrix is rliable's: shape
(runs, tasks), one row per run and one column per task, each entry a score in [0, 1]
(`capture_bench.task.score.episode_score`, or a mean of it). What a run is belongs to the
caller: for the leaderboard an episode (a published seed) and a task a scenario; for the
learning curves a training seed and the one task its scenario.

* **IQM** (``rliable.metrics.aggregate_iqm``): the mean of the middle 50% of all run x task
  scores (25% trimmed from each end), robust to a few outlying runs;
* **optimality gap** (``aggregate_optimality_gap``, gamma = `GAMMA` = 1, the score's
  maximum): 1 - mean(min(score, 1)) over all scores, how far the scores fall short of the
  best possible; lower is better (with every score <= 1 it is 1 - the mean);
* **mean** (``aggregate_mean``): the mean over tasks of each task's mean score;
* **performance profile** (``rliable.library.create_performance_profile``): for each tau in
  [0, 1] (`TAUS`), the share of all run x task scores above tau;
* **probability of improvement** P(X > Y) (``rliable.metrics.probability_of_improvement``): per
  task, the probability that a run of X scores higher than a run of Y (Mann-Whitney U / (n m),
  ties counting 1/2), averaged over tasks.

Every figure carries a 95% percentile interval from rliable's stratified bootstrap
(``rliable.library.get_interval_estimates``): runs resampled with replacement within each task,
`REPS` resamples; for P(X > Y) X's and Y's runs are resampled independently.

Determinism: rliable draws its resamples from numpy's global RandomState (``np.random.choice``;
its ``random_state`` argument does not reach those draws), so each matrix (each pair for P(X > Y))
is bootstrapped in its own call with the global state seeded to `SEED`, and the caller's
state is restored afterwards. An agent's intervals therefore depend on its scores alone (not on
which other agents a report holds), are the same in any process, and move nobody else's stream.

Speed: the IQM, the profile and P(X > Y) handed to rliable's bootstrap are computed here without
scipy's per-call argument handling (IQM: the np.partition of ``scipy.stats.trim_mean``; the
profile: counts from one sort; P(X > Y): the Mann-Whitney counts from ``np.searchsorted``), which
gives rliable's numbers bit for bit (tests/test_rliable_stats.py) in fewer numpy calls; the
optimality gap and the mean are rliable's functions themselves.
"""

from __future__ import annotations

import contextlib
import importlib.util
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: The bootstrap's resamples: enough for stable 95% percentile intervals at the report's size
#: while the default leaderboard's statistics stay about a second (docs/evaluation.md).
REPS = 200
#: numpy's global RandomState is seeded with this for every bootstrap (module docstring).
SEED = 0
CONFIDENCE = 0.95
#: The optimality gap's threshold: the score's maximum.
GAMMA = 1.0
#: The performance profile's thresholds.
TAUS = np.linspace(0.0, 1.0, 51)
#: The aggregate figures of `aggregate_estimates`, in order.
AGGREGATES = ("iqm", "optimality_gap", "mean")
MISSING = "the aggregate statistics need the rliable package: pip install rliable"
CITATION = (
    "Agarwal, Schwarzer, Castro, Courville & Bellemare (2021), Deep Reinforcement Learning at "
    "the Edge of the Statistical Precipice, NeurIPS"
)


class RliableMissing(ImportError):
    """rliable is not installed (the message says how to install it)."""


@dataclass(frozen=True)
class IntervalEstimate:
    """A point estimate and its 95% interval."""

    value: float
    low: float
    high: float

    def as_dict(self) -> dict[str, float]:
        """``{"value", "low", "high"}`` (JSON-ready)."""
        return {"value": self.value, "low": self.low, "high": self.high}


@dataclass(frozen=True)
class Profile:
    """A performance profile: at each threshold ``taus[k]``, the share of scores above it and
    its 95% band; arrays of shape (len(taus),)."""

    taus: np.ndarray
    share: np.ndarray
    low: np.ndarray
    high: np.ndarray


def installed() -> bool:
    """Whether rliable can be imported (without importing it: that takes seconds)."""
    return importlib.util.find_spec("rliable") is not None


def require() -> tuple[Any, Any]:
    """rliable's ``library`` and ``metrics`` modules.

    Raises:
        RliableMissing: rliable is not installed (`MISSING`).
    """
    try:
        from rliable import library, metrics
    except ModuleNotFoundError as exc:
        if exc.name is not None and exc.name.split(".")[0] == "rliable":
            raise RliableMissing(MISSING) from None
        raise
    return library, metrics


@contextlib.contextmanager
def seeded_global_numpy(seed: int = SEED) -> Iterator[None]:
    """numpy's global RandomState seeded with ``seed`` inside, the caller's state after."""
    # rliable's StratifiedBootstrap draws with np.random.choice: the legacy global state it is
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


def check_matrix(name: str, scores: np.ndarray) -> np.ndarray:
    """``scores`` as a float (runs, tasks) matrix with at least one run and one task, all finite.

    Raises:
        ValueError: naming ``name`` and what is wrong.
    """
    matrix = np.asarray(scores, dtype=float)
    if matrix.ndim != 2 or 0 in matrix.shape:
        raise ValueError(f"{name}: a score matrix is (runs, tasks), both > 0, not {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise ValueError(f"{name}: a score matrix holds finite scores only")
    return matrix


def interquartile_mean(scores: np.ndarray) -> float:
    """rliable's IQM (``scipy.stats.trim_mean(scores, 0.25, axis=None)``) by the same steps."""
    flat = np.ravel(scores)
    cut = int(0.25 * flat.size)
    kept = np.partition(flat, (cut, flat.size - cut - 1))[cut : flat.size - cut]
    return float(np.mean(kept))


def _aggregates(metrics: Any) -> Any:
    def statistic(scores: np.ndarray) -> np.ndarray:
        return np.array(
            [
                interquartile_mean(scores),
                metrics.aggregate_optimality_gap(scores, GAMMA),
                metrics.aggregate_mean(scores),
            ]
        )

    return statistic


def aggregate_estimates(
    scores: Mapping[str, np.ndarray], reps: int = REPS, seed: int = SEED
) -> dict[str, dict[str, IntervalEstimate]]:
    """IQM, optimality gap and mean (`AGGREGATES`) of each matrix with its 95% stratified
    bootstrap interval: ``{name: {figure: estimate}}``, in the order of ``scores``."""
    library, metrics = require()
    statistic = _aggregates(metrics)
    out = {}
    for name, matrix in scores.items():
        matrix = check_matrix(name, matrix)
        with seeded_global_numpy(seed):
            points, intervals = library.get_interval_estimates(
                {name: matrix}, statistic, reps=reps, confidence_interval_size=CONFIDENCE
            )
        out[name] = {
            figure: IntervalEstimate(
                float(points[name][k]), float(intervals[name][0, k]), float(intervals[name][1, k])
            )
            for k, figure in enumerate(AGGREGATES)
        }
    return out


def score_distribution(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """rliable's score distribution (``run_score_deviation``: ``np.mean(scores > tau)`` for each
    tau), by counting from one sort."""
    flat = np.sort(scores, axis=None)
    return (flat.size - np.searchsorted(flat, taus, side="right")) / flat.size


def performance_profiles(
    scores: Mapping[str, np.ndarray],
    taus: np.ndarray = TAUS,
    reps: int = REPS,
    seed: int = SEED,
) -> dict[str, Profile]:
    """Each matrix's performance profile (share of scores above each tau) with its 95%
    stratified bootstrap band, in the order of ``scores``."""
    library, _ = require()
    taus = np.asarray(taus, dtype=float)
    out = {}
    for name, matrix in scores.items():
        matrix = check_matrix(name, matrix)
        with seeded_global_numpy(seed):
            profiles, bands = library.create_performance_profile(
                {name: matrix},
                taus,
                custom_profile_func=score_distribution,
                reps=reps,
                confidence_interval_size=CONFIDENCE,
            )
        share = np.asarray(profiles[name], dtype=float)
        band = np.asarray(bands[name], dtype=float)
        out[name] = Profile(taus, share, band[0], band[1])
    return out


def draw_profiles(
    ax: Any,
    profiles: Mapping[str, Profile],
    colours: Mapping[str, Any],
    emphasis: str | None = None,
    unit: str = "episodes",
    styles: Mapping[str, str] | None = None,
) -> None:
    """Draw performance profiles on the matplotlib axes ``ax``: each one's share of scores above
    tau with its 95% band, in ``colours[name]`` and line style ``styles[name]`` (solid where
    ``styles`` names none), ``emphasis`` (a name, or None) drawn thicker and on top; a legend
    outside the curves, in the order of ``profiles``. ``unit`` names what a score belongs to,
    for the y label."""
    styles = styles or {}
    for name, profile in profiles.items():
        thick = name == emphasis
        ax.plot(profile.taus, profile.share, color=colours[name], label=name,
                ls=styles.get(name, "-"), lw=2.6 if thick else 1.5,
                zorder=3 if thick else 2)  # fmt: skip
        ax.fill_between(profile.taus, profile.low, profile.high, color=colours[name], alpha=0.12)
    ax.set_xlabel("score threshold τ (score = physical limit / capture time; 0 for a failure)")
    ax.set_ylabel(f"share of {unit} with score > τ")
    ax.set_xlim(0.0, 1.0)
    ax.set_ylim(-0.02, 1.02)
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.grid(alpha=0.3)


def probability_of_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """rliable's P(X > Y) (``rliable.metrics.probability_of_improvement``: per task
    Mann-Whitney's U of X against Y over n m, averaged over tasks), from the counts of Y's scores
    below and equal to each of X's."""
    n, m = scores_x.shape[0], scores_y.shape[0]
    per_task = []
    for x, y in zip(scores_x.T, np.sort(scores_y, axis=0).T):
        below = np.searchsorted(y, x, side="left")
        not_above = np.searchsorted(y, x, side="right")
        u = below.sum() + 0.5 * (not_above.sum() - below.sum())
        per_task.append(u / (n * m))
    return float(np.mean(per_task))


def improvement_probabilities(
    pairs: Sequence[tuple[str, str]],
    scores: Mapping[str, np.ndarray],
    reps: int = REPS,
    seed: int = SEED,
) -> dict[tuple[str, str], IntervalEstimate]:
    """P(X > Y) with its 95% stratified bootstrap interval for each pair ``(X, Y)`` of names in
    ``scores`` (matrices with the same tasks; their runs may differ in number).

    Raises:
        ValueError: a pair whose matrices have different numbers of tasks.
    """
    library, _ = require()
    out = {}
    for x, y in pairs:
        a, b = check_matrix(x, scores[x]), check_matrix(y, scores[y])
        if a.shape[1] != b.shape[1]:
            raise ValueError(f"P({x} > {y}): {a.shape[1]} tasks against {b.shape[1]}")
        key = f"{x},{y}"
        with seeded_global_numpy(seed):
            points, intervals = library.get_interval_estimates(
                {key: (a, b)},
                probability_of_improvement,
                reps=reps,
                confidence_interval_size=CONFIDENCE,
            )
        band = np.ravel(intervals[key])
        out[(x, y)] = IntervalEstimate(float(points[key]), float(band[0]), float(band[1]))
    return out
