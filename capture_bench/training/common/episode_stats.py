"""Task statistics of training episodes, from the per-step ``info`` dicts (no SB3 here).

What ``train.py`` logs to TensorBoard beside SB3's own scalars, under ``rollout/`` (the training
episodes that ended since the last time the logger wrote) and ``eval/`` (the periodic validation
episodes): the keys of `summarize`.

================================  ================================================================
key                               statistic over the episodes
================================  ================================================================
``capture_rate``                  share of episodes that captured (``is_success`` at the end)
``median_capture_time``           median ``capture_time`` of the captured episodes, s
``median_ratio_to_limit``         median of ``capture_time / physical_limit_time`` over the
                                  captured episodes whose bound is finite and > 0 (the
                                  leaderboard's ratio to the physical limit)
``mean_score``                    mean of the per-episode score
                                  (`capture_bench.task.score.episode_score`: physical
                                  limit / capture time for a capture, 0 for a failure)
``failure/<reason>``              share of episodes that ended with ``failure == reason``, for
                                  each reason of `FAILURES`
``estimate_position_error_m``     mean over episodes of each episode's mean
                                  ``estimate_position_error`` (m) over its steps where it is
                                  finite (steps without a valid estimate are left out; an episode
                                  with none is left out)
``mean_reward``                   mean undiscounted episode return (only where rewards are given)
================================  ================================================================

A statistic with no episode to compute it on (no capture, no estimate) is NaN in
`summarize`'s result; loggers leave NaN out (`finite_items`). An episode is read by
`capture_bench.task.accounting`, as the evaluation's records are: "captured", the failure reason
and the ratio mean the same here and on the leaderboard.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from capture_bench.task.accounting import EstimateLog, episode_outcome, info_number
from capture_bench.task.score import episode_score
from capture_bench.task.step_rule import FAILURES

NAN = float("nan")


@dataclass(frozen=True)
class EpisodeStats:
    """What one ended episode contributes to the statistics.

    Attributes:
        captured: the episode ended with a capture (``is_success`` of its last step).
        failure: its failure reason (one of ``FAILURES``), None if it captured.
        capture_time: time of capture, s; NaN if it did not capture.
        physical_limit_time: its lower bound on capture time, s (inf: none); NaN if not reported.
        ratio_to_limit: ``capture_time / physical_limit_time``; NaN unless captured with a finite
            bound > 0.
        estimate_position_error_m: mean over its steps of the finite ``estimate_position_error``,
            m; NaN if no step had one.
        reward: undiscounted return; NaN if the rewards were not given.
    """

    captured: bool
    failure: str | None
    capture_time: float
    physical_limit_time: float
    ratio_to_limit: float
    estimate_position_error_m: float
    reward: float = NAN


def episode_stats(
    final_info: Mapping[str, Any],
    position_errors: Iterable[float],
    reward: float = NAN,
) -> EpisodeStats:
    """The statistics of an episode from the ``info`` of its last step and the
    ``estimate_position_error`` of each of its steps (m; NaN entries are left out). A time limit
    outside the environment (SB3's ``TimeLimit.truncated``) makes an unnamed failure a
    ``timeout``, as in the evaluation."""
    outcome = episode_outcome(final_info, bool(final_info.get("TimeLimit.truncated", False)))
    log = EstimateLog()
    for error in position_errors:
        log.add(error, NAN, NAN, False)
    return EpisodeStats(
        captured=outcome.captured,
        failure=outcome.failure or None,
        capture_time=outcome.capture_time,
        physical_limit_time=outcome.physical_limit_time,
        ratio_to_limit=outcome.ratio,
        estimate_position_error_m=log.position_error_mean,
        reward=float(reward),
    )


class EpisodeTracker:
    """Follows ``n_envs`` episodes step by step and returns each one's statistics as it ends.

    Feed it every step of a vector env, SB3 style (a list of per-env ``info`` dicts with the
    single env's keys, and the ``dones``); the step where env i is done is its episode's last.
    """

    def __init__(self, n_envs: int) -> None:
        self._errors: list[list[float]] = [[] for _ in range(n_envs)]
        self._rewards = np.zeros(n_envs)

    def step(
        self,
        infos: Sequence[Mapping[str, Any]],
        dones: Sequence[bool] | np.ndarray,
        rewards: Sequence[float] | np.ndarray | None = None,
    ) -> list[tuple[int, EpisodeStats]]:
        """Take one step of every env; ``(env index, statistics)`` of the episodes that ended."""
        if rewards is not None:
            self._rewards += np.asarray(rewards, dtype=float)
        ended = []
        for i, info in enumerate(infos):
            self._errors[i].append(info_number(info, "estimate_position_error"))
            if dones[i]:
                reward = float(self._rewards[i]) if rewards is not None else NAN
                ended.append((i, episode_stats(info, self._errors[i], reward)))
                self._errors[i] = []
                self._rewards[i] = 0.0
        return ended


def _median(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.median(finite)) if finite else NAN


def _mean(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else NAN


def summarize(episodes: Sequence[EpisodeStats]) -> dict[str, float]:
    """The statistics of the module docstring's table over ``episodes`` (NaN where undefined;
    every key is present, ``mean_reward`` only if some episode has a reward)."""
    n = len(episodes)
    result = {
        "capture_rate": sum(e.captured for e in episodes) / n if n else NAN,
        "median_capture_time": _median([e.capture_time for e in episodes if e.captured]),
        "median_ratio_to_limit": _median([e.ratio_to_limit for e in episodes if e.captured]),
        "mean_score": _mean([episode_score(e.captured, e.ratio_to_limit) for e in episodes]),
    }
    for reason in FAILURES:
        result[f"failure/{reason}"] = sum(e.failure == reason for e in episodes) / n if n else NAN
    result["estimate_position_error_m"] = _mean([e.estimate_position_error_m for e in episodes])
    if any(not math.isnan(e.reward) for e in episodes):
        result["mean_reward"] = _mean([e.reward for e in episodes])
    return result


def finite_items(stats: Mapping[str, float]) -> dict[str, float]:
    """The entries of ``stats`` that are finite numbers (what goes to TensorBoard)."""
    return {k: v for k, v in stats.items() if math.isfinite(v)}
