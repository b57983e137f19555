"""Leaderboard statistics: pure functions of episode records.

Every figure that is an estimate carries a 95% confidence interval:

* capture rate: Wilson score interval;
* capture time (median, IQM over *captured* episodes), ratio to the physical limit, distance and
  relative speed at capture, estimator errors, path length, saturation share: percentile bootstrap
  (``scipy.stats.bootstrap``, 2,000 resamples, fixed seed ``BOOTSTRAP_SEED``, so two runs agree);
* time to capture with failures as **censored** observations: Kaplan-Meier survival curve of
  "not yet captured" (``scipy.stats.ecdf``), each failure censored at the time its episode ended,
  with log-log pointwise bands; its median (the time by which half the episodes are captured) gets
  the interval obtained by inverting those bands (Brookmeyer-Crowley style). Caveat: a collision
  or a lost target is *informative* censoring (that episode would never have captured), so the
  KM curve is optimistic for agents that fail early; read it next to the capture rate.

Paired comparison with the reference agent (``incremental_ik``), on the seeds both ran:

* each seed's outcome is its capture time, a failure counts as +inf (worse than any capture);
* probability of improvement = mean over seeds of 1 if the agent's outcome is strictly better,
  1/2 if tied (both failed, or equal times), 0 if worse; bootstrap interval over seeds;
* paired capture-time difference = median over seeds where *both* captured of
  (agent time - reference time), s, negative is faster; bootstrap interval over those seeds.
  Seeds where only one side captured are counted (``only_agent``, ``only_reference``) and shown,
  never folded into the difference.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 20160101
NAN = float("nan")


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its 95% interval; NaN where undefined (e.g. no data)."""

    value: float
    low: float = NAN
    high: float = NAN

    def contains_value(self) -> bool:
        """True if the interval is undefined or contains the point estimate."""
        if any(math.isnan(v) for v in (self.value, self.low, self.high)):
            return True
        return self.low - 1e-12 <= self.value <= self.high + 1e-12


def wilson_interval(successes: int, trials: int, confidence: float = CONFIDENCE) -> Estimate:
    """Proportion ``successes / trials`` with its Wilson score interval (NaN if ``trials == 0``)."""
    if trials <= 0:
        return Estimate(NAN)
    p = successes / trials
    z = float(stats.norm.ppf(0.5 + confidence / 2))
    denom = 1 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    return Estimate(p, max(0.0, centre - half), min(1.0, centre + half))


def interquartile_mean(values: np.ndarray, axis: int = -1) -> np.ndarray:
    """Mean of the middle 50% of the values (25% trimmed from each end)."""
    return stats.trim_mean(values, 0.25, axis=axis)


def _median(values: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.median(values, axis=axis)


def _mean(values: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.mean(values, axis=axis)


STATISTICS: dict[str, Callable[..., np.ndarray]] = {
    "median": _median,
    "iqm": interquartile_mean,
    "mean": _mean,
}


def bootstrap_estimate(values: Sequence[float] | np.ndarray, statistic: str) -> Estimate:
    """``statistic`` ('median', 'iqm' or 'mean') of the finite values, with a 95% percentile
    bootstrap interval (fixed seed). NaN estimate if there is no finite value; NaN interval if
    there are fewer than two."""
    data = np.asarray(values, dtype=float)
    data = data[np.isfinite(data)]
    func = STATISTICS[statistic]
    if data.size == 0:
        return Estimate(NAN)
    value = float(func(data))
    if data.size < 2:
        return Estimate(value)
    if np.all(data == data[0]):
        return Estimate(value, value, value)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = stats.bootstrap(
            (data,),
            func,
            confidence_level=CONFIDENCE,
            n_resamples=BOOTSTRAP_RESAMPLES,
            method="percentile",
            vectorized=True,
            rng=np.random.default_rng(BOOTSTRAP_SEED),
        )
    return Estimate(
        value, float(result.confidence_interval.low), float(result.confidence_interval.high)
    )


@dataclass(frozen=True)
class SurvivalCurve:
    """Kaplan-Meier estimate of P(not captured by time t), failures censored at their end time.

    Attributes:
        time: step times, s, increasing, starting at 0.
        survival: S(t) just after each time (right-continuous step function).
        low, high: pointwise 95% log-log band.
    """

    time: np.ndarray
    survival: np.ndarray
    low: np.ndarray
    high: np.ndarray

    def median(self) -> Estimate:
        """First time S(t) <= 1/2 (inf if never), interval from the bands."""

        def first_below(curve: np.ndarray) -> float:
            hits = np.nonzero(curve <= 0.5)[0]
            return float(self.time[hits[0]]) if hits.size else math.inf

        return Estimate(first_below(self.survival), first_below(self.low), first_below(self.high))


def kaplan_meier(end_times: Sequence[float], captured: Sequence[bool]) -> SurvivalCurve:
    """Survival of time-to-capture: captured episodes are events at their capture time, failed
    ones are right-censored at the time they ended (s)."""
    t = np.asarray(end_times, dtype=float)
    c = np.asarray(captured, dtype=bool)
    if t.size == 0:
        empty = np.array([0.0])
        return SurvivalCurve(empty, np.ones(1), np.ones(1), np.ones(1))
    if not c.any():
        times = np.concatenate([[0.0], np.unique(t)])
        ones = np.ones_like(times)
        return SurvivalCurve(times, ones, ones.copy(), ones.copy())
    data = stats.CensoredData(uncensored=t[c], right=t[~c])
    sf = stats.ecdf(data).sf
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        band = sf.confidence_interval(CONFIDENCE, method="log-log")
    # the log-log band is undefined where S is 0 or 1; it collapses onto S there
    low = np.where(np.isnan(band.low.probabilities), sf.probabilities, band.low.probabilities)
    high = np.where(np.isnan(band.high.probabilities), sf.probabilities, band.high.probabilities)
    return SurvivalCurve(
        time=np.concatenate([[0.0], sf.quantiles]),
        survival=np.concatenate([[1.0], sf.probabilities]),
        low=np.concatenate([[1.0], low]),
        high=np.concatenate([[1.0], high]),
    )


@dataclass(frozen=True)
class PairedComparison:
    """An agent against the reference agent on the seeds both ran (see module docstring)."""

    pairs: int
    prob_improvement: Estimate
    time_difference: Estimate
    both_captured: int
    only_agent: int
    only_reference: int
    neither: int


def paired_comparison(
    agent_times: dict[int, float], reference_times: dict[int, float]
) -> PairedComparison:
    """Compare per-seed outcomes: capture time in s, ``inf`` for a failed episode.

    Args:
        agent_times: seed -> the agent's outcome.
        reference_times: seed -> the reference agent's outcome.
    """
    seeds = sorted(set(agent_times) & set(reference_times))
    a = np.array([agent_times[s] for s in seeds], dtype=float)
    b = np.array([reference_times[s] for s in seeds], dtype=float)
    scores = np.where(a < b, 1.0, np.where(a == b, 0.5, 0.0))
    both = np.isfinite(a) & np.isfinite(b)
    return PairedComparison(
        pairs=len(seeds),
        prob_improvement=bootstrap_estimate(scores, "mean"),
        time_difference=bootstrap_estimate(a[both] - b[both], "median"),
        both_captured=int(both.sum()),
        only_agent=int((np.isfinite(a) & ~np.isfinite(b)).sum()),
        only_reference=int((~np.isfinite(a) & np.isfinite(b)).sum()),
        neither=int((~np.isfinite(a) & ~np.isfinite(b)).sum()),
    )
