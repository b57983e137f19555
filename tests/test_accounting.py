"""The one accounting of an episode (capture_bench.task.accounting) that the evaluation's records
and the training's statistics both read, held against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capture_bench.task.accounting import (
    UNSPECIFIED_FAILURE,
    EstimateLog,
    episode_outcome,
    ratio_to_limit,
)


def test_a_capture_has_its_time_and_ratio_and_no_failure():
    out = episode_outcome({"is_success": True, "capture_time": 2.5, "physical_limit_time": 2.0})
    assert (out.captured, out.failure, out.capture_time, out.ratio) == (True, "", 2.5, 1.25)


def test_a_given_limit_overrides_the_infos():
    out = episode_outcome({"is_success": True, "capture_time": 3.0, "physical_limit_time": 2.0},
                          limit=1.5)  # fmt: skip
    assert (out.physical_limit_time, out.ratio) == (1.5, 2.0)


@pytest.mark.parametrize(
    ("info", "truncated", "failure"),
    [
        ({"failure": "collision"}, False, "collision"),
        ({"failure": "collision"}, True, "collision"),  # the env's own reason wins
        ({}, True, "timeout"),  # cut by a time limit outside the env
        ({}, False, UNSPECIFIED_FAILURE),  # kept visible, never silently a capture
    ],
)
def test_a_failure_has_a_reason_and_no_time(info, truncated, failure):
    out = episode_outcome({"is_success": False, "capture_time": 9.0, **info}, truncated)
    assert not out.captured and out.failure == failure
    assert math.isnan(out.capture_time) and math.isnan(out.ratio)


@pytest.mark.parametrize("limit", [math.inf, 0.0, -1.0, math.nan])
def test_no_ratio_without_a_finite_positive_bound(limit):
    assert math.isnan(ratio_to_limit(1.0, limit))


def test_the_estimate_log_by_hand():
    log = EstimateLog()
    for position, velocity, nees, saturated in [(3.0, 1.0, 2.0, True), (math.nan,) * 3 + (False,),
                                                (4.0, 1.0, math.inf, True)]:  # fmt: skip
        log.add(position, velocity, nees, saturated)
    assert log.steps == 3
    assert log.position_rmse == pytest.approx(math.sqrt((9 + 16) / 2))
    assert log.velocity_rmse == pytest.approx(1.0)
    assert log.position_error_mean == pytest.approx(3.5)
    assert log.mean_nees == 2.0  # an infinite NEES is left out with the missing one
    assert log.saturated_share == pytest.approx(2 / 3)


def test_an_episode_without_any_estimate_is_nan_without_a_warning():
    log = EstimateLog()
    assert math.isnan(log.saturated_share)
    with np.errstate(all="raise"):
        log.add(math.nan, math.nan, math.nan, False)
        assert math.isnan(log.position_rmse) and math.isnan(log.position_error_mean)
