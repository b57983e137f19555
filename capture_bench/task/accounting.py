"""One episode's accounting from the environment's ``info``: whether and when it captured, why it
failed, its ratio to the physical limit, and its estimate errors step by step.

The evaluation's records (`capture_bench.evaluation.running.rollout`) and the training's statistics
(`capture_bench.training.common.episode_stats`) both read an episode through this module, so a
capture, a failure and a ratio mean the same in a training log and on the leaderboard.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: The reason of a failed episode whose ``info`` names none and which no time limit cut (the
#: environment always names one; kept visible should one ever be missing).
UNSPECIFIED_FAILURE = "unspecified"


def info_number(info: Mapping[str, Any], key: str) -> float:
    """``info[key]`` as a float; NaN where it is missing or None."""
    value = info.get(key)
    return math.nan if value is None else float(value)


def ratio_to_limit(capture_time: float, physical_limit_time: float) -> float:
    """``capture_time / physical_limit_time``; NaN for a NaN time or a bound that is not finite
    and positive."""
    if math.isnan(capture_time) or not (
        math.isfinite(physical_limit_time) and physical_limit_time > 0
    ):
        return math.nan
    return capture_time / physical_limit_time


@dataclass(frozen=True)
class Outcome:
    """How an episode ended.

    Attributes:
        captured: it ended with a capture (``is_success`` of its last step).
        failure: its failure reason (``timeout``, ``collision``, ``target_lost``,
            ``unreachable``), ``""`` if it captured.
        capture_time: time of capture, s; NaN if it did not capture.
        physical_limit_time: its lower bound on capture time, s (inf: none; NaN: not known).
        ratio: ``capture_time / physical_limit_time`` (`ratio_to_limit`).
    """

    captured: bool
    failure: str
    capture_time: float
    physical_limit_time: float
    ratio: float


def episode_outcome(
    final_info: Mapping[str, Any], truncated: bool = False, limit: float | None = None
) -> Outcome:
    """The outcome from the ``info`` of an episode's last step.

    Args:
        final_info: the last step's ``info`` (the single env's form).
        truncated: a time limit outside the environment cut the episode: a failure the ``info``
            does not name is then a ``timeout``.
        limit: the episode's physical limit, s; default the ``info``'s ``physical_limit_time``.
    """
    captured = bool(final_info.get("is_success", False))
    failure = "" if captured else final_info.get("failure") or ("timeout" if truncated else "")
    if not captured and not failure:
        failure = UNSPECIFIED_FAILURE
    capture_time = info_number(final_info, "capture_time") if captured else math.nan
    bound = info_number(final_info, "physical_limit_time") if limit is None else float(limit)
    return Outcome(captured, str(failure), capture_time, bound, ratio_to_limit(capture_time, bound))


class EstimateLog:
    """An episode's estimate errors, NEES and joint-rate saturation, step by step (NaN: a step
    without a valid estimate)."""

    def __init__(self) -> None:
        self.position_errors: list[float] = []
        self.velocity_errors: list[float] = []
        self.nees: list[float] = []
        self.saturated = 0

    @property
    def steps(self) -> int:
        """Steps logged."""
        return len(self.position_errors)

    def add(self, position_error: float, velocity_error: float, nees: float, saturated: bool):
        """One step's ``estimate_position_error`` (m), ``estimate_velocity_error`` (m/s),
        ``estimate_nees`` and ``saturated``."""
        self.position_errors.append(position_error)
        self.velocity_errors.append(velocity_error)
        self.nees.append(nees)
        self.saturated += bool(saturated)

    def add_info(self, info: Mapping[str, Any]) -> None:
        """One step, read from its ``info`` (the single env's form)."""
        self.add(
            info_number(info, "estimate_position_error"),
            info_number(info, "estimate_velocity_error"),
            info_number(info, "estimate_nees"),
            bool(info.get("saturated", False)),
        )

    @property
    def position_rmse(self) -> float:
        """RMS over the steps with an estimate of the position error, m; NaN if none had one."""
        return _root_mean_square(self.position_errors)

    @property
    def velocity_rmse(self) -> float:
        """RMS over the steps with an estimate of the velocity error, m/s; NaN if none had one."""
        return _root_mean_square(self.velocity_errors)

    @property
    def position_error_mean(self) -> float:
        """Mean over the steps with an estimate of the position error, m; NaN if none had one."""
        return _finite_mean(self.position_errors)

    @property
    def mean_nees(self) -> float:
        """Mean NEES over the steps that have one; NaN if none has."""
        return _finite_mean(self.nees)

    @property
    def saturated_share(self) -> float:
        """Share of the steps in which some joint ran at its rate limit; NaN before any step."""
        return self.saturated / self.steps if self.steps else math.nan


def _finite_mean(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def _root_mean_square(values: list[float]) -> float:
    """sqrt of the mean square of the ``values`` that are not NaN (numpy's ``nanmean`` of the
    squares), NaN where all are (an episode whose estimator never had an estimate), without
    numpy's warning."""
    squares = np.asarray([v**2 for v in values], dtype=float)
    if np.isnan(squares).all():  # an empty list too
        return math.nan
    return float(np.sqrt(np.nanmean(squares)))
