"""The capture envelope: eq. 20's box, the end-effector's instantaneous velocity relative to the
capture point at most ``capture.v_max``, both held for ``capture.hold``. The relative velocity
against a finite difference of forward kinematics, the slow stretches of a step against a brute
force, and whole episodes: a sweep through the target at full joint rate never captures, a
controller that lands and tracks does."""

from __future__ import annotations

import numpy as np
import pytest
from references.relative_velocities_einsum import relative_velocities as einsum_velocities

from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.evaluation.running.rollout import run_episode
from capture_bench.sim.kinematics import JOINT_LOWER, JOINT_UPPER, arm_pose, forward_kinematics
from capture_bench.task.capture import (
    VELOCITY_RESOLUTION,
    intersect,
    relative_velocities,
    slow_intervals,
    slow_intervals_along_arc,
)
from capture_bench.task.scenarios import ConfigError, load_scenario

SEEDS = range(1_000_100, 1_000_106)  # validation seeds of paper


def _step(rng: np.random.Generator):
    theta0 = rng.uniform([-1.0, -0.3, -0.6], [1.0, 0.6, 0.6])
    delta = rng.uniform(-0.5, 0.5, 3) * rng.choice([0.02, 0.3, 1.0])
    target_velocity = rng.normal(0.0, 0.05, 3)
    return theta0, delta, 0.05, target_velocity


@pytest.mark.parametrize("seed", range(20))
def test_the_relative_velocity_along_an_arc_is_the_derivative_of_forward_kinematics(seed):
    rng = np.random.default_rng(seed)
    theta0, delta, dt, xdot_t = _step(rng)
    s, h = rng.uniform(0.1, 0.9), 1e-6
    # X_E(t0 + s dt) by forward kinematics, differentiated in time by central differences
    ahead, behind = (forward_kinematics(theta0 + (s + d) * delta) for d in (h, -h))
    finite = (ahead - behind) / (2 * h * dt) - xdot_t
    pose = arm_pose((theta0 + s * delta)[None])
    exact = relative_velocities(pose, (delta / dt)[None], xdot_t[None])[0]
    np.testing.assert_allclose(exact, finite, atol=1e-7)


def test_the_relative_velocity_is_the_jacobian_times_the_joint_rates_minus_the_target_velocity():
    """The multiplied-out entries against the matrix product with eq. 9's Jacobian, over joint
    angles inside and well outside the limits."""
    rng = np.random.default_rng(7)
    n = 2000
    theta = rng.uniform(JOINT_LOWER - 1.0, JOINT_UPPER + 1.0, (n, 3))
    rates = rng.uniform(-1.0, 1.0, (n, 3)) * rng.choice([1e-3, 0.4, 10.0], (n, 1))
    xdot_t = rng.normal(0.0, 0.5, (n, 3))
    ours = relative_velocities(arm_pose(theta), rates, xdot_t)
    reference = einsum_velocities(theta, rates, xdot_t)
    relative = np.abs(ours - reference).max(axis=1) / np.linalg.norm(reference, axis=1)
    assert relative.max() < 1e-12


@pytest.mark.parametrize("seed", range(50))
def test_slow_intervals_of_a_straight_velocity_match_a_brute_force(seed):
    rng = np.random.default_rng(seed)
    v0, v1 = rng.normal(0, 0.1, (2, 1, 3))
    v_max = float(rng.uniform(0.01, 0.2))
    u = np.linspace(0.0, 1.0, 20_001)
    speed = np.linalg.norm(v0 + u[:, None] * (v1 - v0), axis=1)
    lo, hi = slow_intervals(v0, v1, v_max)
    inside = ~np.isnan(lo[0]) & (u >= lo[0]) & (u <= hi[0])
    clear = np.abs(speed - v_max) > 1e-9
    assert np.array_equal(inside[clear], (speed <= v_max)[clear])


@pytest.mark.parametrize("seed", range(30))
def test_slow_intervals_along_an_arc_match_a_brute_force(seed):
    rng = np.random.default_rng(seed)
    theta0, delta, dt, xdot_t = _step(rng)
    target_velocity_at = lambda f: np.tile(xdot_t, (np.size(f), 1))  # noqa: E731
    s = np.linspace(0.0, 1.0, 4001)
    theta = theta0[None] + s[:, None] * delta[None]
    speed = np.linalg.norm(
        relative_velocities(
            arm_pose(theta), np.tile(delta / dt, (s.size, 1)), target_velocity_at(s)
        ),
        axis=1,
    )
    v_max = float(np.quantile(speed, rng.uniform(0.2, 0.8)))
    intervals = slow_intervals_along_arc(theta0, delta, dt, target_velocity_at, v_max)
    inside = np.zeros(s.size, bool)
    for lo, hi in intervals:
        inside |= (s >= lo) & (s <= hi)
    assert not (inside & (speed > v_max + VELOCITY_RESOLUTION)).any()
    assert not (~inside & (speed < v_max - VELOCITY_RESOLUTION)).any()
    assert all(a[1] < b[0] for a, b in zip(intervals, intervals[1:]))  # in order, disjoint


def test_intersect_keeps_what_both_hold():
    assert intersect([(0.0, 0.5), (0.6, 1.0)], [(0.2, 0.7)]) == [(0.2, 0.5), (0.6, 0.7)]
    assert intersect([(0.0, 0.5)], [(0.5, 1.0)]) == []  # touching is no stay
    assert intersect([], [(0.0, 1.0)]) == []


def _captures(agent_name: str, **capture) -> int:
    scenario = load_scenario("paper").replace(capture=capture, capture_tolerance=0.005)
    env = CaptureEnv(scenario)
    agent = make_agent(agent_name, env)
    captured = 0
    try:
        for seed in SEEDS:
            record, _ = run_episode(env, agent, agent_name=agent_name, scenario="paper", seed=seed)
            captured += record.outcome == "captured"
    finally:
        env.close()
    return captured


def test_a_sweep_through_the_target_at_full_joint_rate_never_captures():
    """joint_intercept_uncapped drives every joint at full rate through the earliest pose that
    meets the target: inside a 5 mm box it captures every episode, under a 50 mm/s bound none."""
    assert _captures("joint_intercept_uncapped", v_max=None, hold=0.0) == len(SEEDS)
    assert _captures("joint_intercept_uncapped", v_max=0.05, hold=0.0) == 0


@pytest.mark.parametrize(
    "agent", ["incremental_ik", "joint_intercept", "joint_intercept_dls", "oracle"]
)
def test_a_controller_that_lands_and_tracks_captures_under_the_envelope(agent):
    assert _captures(agent, v_max=0.05, hold=0.2) == len(SEEDS)


@pytest.mark.parametrize("value", [-0.1, 0, 11, "fast", [0.05]])
def test_an_envelope_key_out_of_range_is_one_line_naming_the_key(value):
    with pytest.raises(ConfigError) as raised:
        load_scenario("paper").replace(capture={"v_max": value})
    message = str(raised.value)
    assert "key 'capture.v_max'" in message and "expected a number in (0, 10] or null" in message
    assert "\n" not in message
