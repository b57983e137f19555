"""The step rule's defined sets, exposed exactly by both envs; the scalar fast paths against
their batched forms; the episode cache's public interface."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import capture_bench  # noqa: F401  (registers the envs)
from capture_bench.envs import capture_env
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.evaluation.aggregate import KNOWN_FAILURES
from capture_bench.sensing.estimator import TargetEstimate
from capture_bench.task.recording import STEP_TRACKS, estimate_errors, estimate_errors_scalar
from capture_bench.task.rewards import REWARD_MODES, REWARD_TERMS
from capture_bench.task.step_rule import (
    END_INFO_KEYS,
    FAILURE_NAMES,
    FAILURES,
    INFO_KEYS,
    RESET_INFO_KEYS,
    info_keys,
)
from capture_bench.task.target_side import EpisodeCache


def _drive(env, seed, steps, rng):
    """Reset, then step with random actions; every (reward, info) and the reset info."""
    _, reset_info = env.reset(seed=seed)
    out = []
    for _ in range(steps):
        _, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, 3))
        out.append((reward, terminated or truncated, info))
        if terminated or truncated:
            break
    return reset_info, out


@pytest.mark.parametrize("reward", REWARD_MODES)
def test_single_env_exposes_exactly_the_defined_info_keys_and_reward_terms(reward):
    env = CaptureEnv("paper", reward=reward)
    rng = np.random.default_rng(0)
    try:
        for seed in range(3):
            reset_info, steps = _drive(env, seed, 400, rng)
            assert tuple(reset_info) == RESET_INFO_KEYS
            for reward_value, ended, info in steps:
                expected = info_keys(reward) + (END_INFO_KEYS if ended else ())
                assert tuple(info) == expected
                terms = [info[name] for name in REWARD_TERMS[reward]]
                assert reward_value == pytest.approx(sum(terms), abs=1e-12)
                assert info["failure"] is None or info["failure"] in FAILURES
                assert isinstance(info["failure"], (str, type(None)))
                assert info["capture_time"] is None or isinstance(info["capture_time"], float)
                for key in ("time", "dt", "distance", "path_length", "estimate_nees"):
                    assert type(info[key]) is float, key
                for key in ("is_success", "saturated", "clipped", "target_visible"):
                    assert type(info[key]) is bool, key
            assert steps[-1][1] and steps[-1][2]["failure"] in FAILURES + (None,)
    finally:
        env.close()


@pytest.mark.parametrize("reward", REWARD_MODES)
def test_vector_env_exposes_exactly_the_defined_info_keys_and_reward_terms(reward):
    env = CaptureVectorEnv(4, "paper", reward=reward)
    rng = np.random.default_rng(0)
    try:
        _, reset_info = env.reset(seed=0)
        assert {k for k in reset_info if not k.startswith("_")} == set(RESET_INFO_KEYS)
        for _ in range(120):
            _, rewards, *_, info = env.step(rng.uniform(-1, 1, (4, 3)))
            keys = [k for k in info if not k.startswith("_")]
            assert tuple(keys) == info_keys(reward) + END_INFO_KEYS
            stepped = info["_is_success"]
            terms = sum(info[name] for name in REWARD_TERMS[reward])
            np.testing.assert_allclose(rewards[stepped], terms[stepped], atol=1e-12)
            assert set(info["failure"][stepped]) <= {None, *FAILURES}
    finally:
        env.close()


def test_one_list_of_failure_reasons():
    """The envs, the vector env's codes and the report's columns use the step rule's list; the
    env documents each."""
    assert capture_env.FAILURES is FAILURES
    assert tuple(FAILURE_NAMES[1:]) == FAILURES and FAILURE_NAMES[0] is None
    assert tuple(KNOWN_FAILURES) == FAILURES
    for reason in FAILURES:
        assert reason in CaptureEnv.__doc__
    for key in INFO_KEYS + END_INFO_KEYS:
        assert f"``{key}``" in CaptureEnv.__doc__, key


def test_estimate_errors_scalar_equals_the_batched_form():
    rng = np.random.default_rng(3)
    n = 40
    pos, vel = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    true_pos, true_vel = pos + 0.01 * rng.normal(size=(n, 3)), vel + 0.1 * rng.normal(size=(n, 3))
    a = rng.normal(size=(n, 6, 6))
    cov = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(6)
    cov[5] = -np.eye(6)  # not positive definite: NaN
    cov[6] = np.nan  # no covariance
    valid = rng.uniform(size=n) > 0.2
    batched = estimate_errors(pos, vel, cov, valid, true_pos, true_vel)
    for k in range(n):
        covariance = None if k == 6 else cov[k]
        estimate = TargetEstimate(pos[k], vel[k], covariance, bool(valid[k]), "ok")
        scalar = estimate_errors_scalar(estimate, true_pos[k], true_vel[k])
        np.testing.assert_allclose(scalar, [b[k] for b in batched], rtol=1e-12)


def test_an_env_given_its_own_episode_cache_keeps_recordings_there_and_clear_empties_it():
    cache = EpisodeCache()
    env = gym.make("CaptureBench/Paper-v0", reuse_target_side=True, episode_cache=cache)
    try:
        env.reset(seed=4)
        key = (env.unwrapped.scenario, 4)
        assert cache.recorded_keys() == [key]
        episode, _state = cache.recording(key)
        assert env.unwrapped.recorded_episode is episode
        limit = env.unwrapped.physical_limit()
        assert cache.limit(key) is limit
        cache.clear()
        assert cache.recorded_keys() == [] and cache.limit(key) is None
        env.reset(seed=4)  # recorded again: the same episode, a new object
        again = env.unwrapped.recorded_episode
        assert again is not episode
        np.testing.assert_array_equal(again.estimate_position, episode.estimate_position)
    finally:
        env.close()


@pytest.mark.parametrize(
    ("scenario", "source", "reward"),
    [
        ("paper", None, "dense"),
        ("jitter", None, "dense"),
        ("noisy", None, "sparse"),
        ("tumbling", "truth", "dense"),
        ("circular", None, "shaped"),
        ("grasp", None, "dense"),  # a hold: stays carried from step to step, on both tests
    ],
)
def test_the_single_envs_scalar_step_equals_the_batched_rule(scenario, source, reward):
    """StepRule.step_scalar (the single env's fast path) against StepRule.step at N = 1 on the
    same recorded episodes and the same arm motion: every returned value, every info entry and
    the carried state. The motion closes on the target (so steps capture, and the arc test runs
    near it) or wanders (so failures happen)."""
    from agents import make_agent
    from capture_bench.sim import kinematics
    from capture_bench.sim.world import limit_joint_increments
    from capture_bench.task.step_rule import ArmState, scalar_info

    env = CaptureEnv(scenario, observation_source=source, reward=reward, reuse_target_side=True)
    agent = make_agent("incremental_ik", env)
    rule, arm = env.rule, env.description.arm
    rng = np.random.default_rng(1)
    compared = captured = 0
    try:
        for seed in range(8):
            obs, _ = env.reset(seed=seed)
            episode = env.recorded_episode
            scalar, batched = ArmState.empty(1), ArmState.empty(1)
            for state in (scalar, batched):
                rule.start(state, slice(None), episode.position[:1])
            wander = seed % 2 == 1
            for k in range(1, episode.time.size):
                action = rng.uniform(-1, 1, 3) if wander else agent.predict(obs)[0]
                request = env.description.action_to_increment(np.clip(action, -1, 1))
                dt = episode.dt[k : k + 1]
                theta, clipped, saturated = limit_joint_increments(
                    scalar.theta.copy(), request[None], dt, arm
                )
                x_e = kinematics.forward_kinematics(theta)
                collide = bool(rng.random() < 0.02)  # the world's answer, the same for both
                reward_s, term_s, trunc_s, info_s = rule.step_scalar(
                    scalar, episode, k, theta[0], x_e[0], bool(clipped[0]), bool(saturated[0]),
                    lambda collide=collide: collide, env.plan.trajectory,
                )  # fmt: skip
                rows = {n: getattr(episode, n)[k - 1 : k] for n in STEP_TRACKS}
                after = {n: getattr(episode, n)[k : k + 1] for n in STEP_TRACKS}
                out = rule.step(
                    batched, slice(None), rows, after, theta, x_e, clipped, saturated,
                    lambda ask, collide=collide: ask & collide, lambda j: env.plan.trajectory,
                )  # fmt: skip
                info_b = scalar_info(out.info)
                assert tuple(info_s) == tuple(info_b) == info_keys(reward)
                for key, value in info_s.items():
                    other = info_b[key]
                    if isinstance(value, float):  # abs: reward_progress is 10 (d_prev - d), and
                        # while the arm holds on the target d_prev ~ d: the sum's rounding shows
                        assert value == pytest.approx(other, rel=1e-12, abs=1e-14, nan_ok=True), key
                    else:
                        assert value == other, key
                assert reward_s == pytest.approx(float(out.reward[0]), rel=1e-12, abs=1e-14)
                assert (term_s, trunc_s) == (bool(out.terminated[0]), bool(out.truncated[0]))
                for name in ("theta", "x_e", "distance", "path_length", "since_frame",
                             "unreachable_for", "capture_time_estimated", "inside_since",
                             "estimate_inside_since"):  # fmt: skip
                    np.testing.assert_allclose(
                        getattr(scalar, name), getattr(batched, name), rtol=1e-12, atol=1e-15
                    )
                compared += 1
                captured += info_s["is_success"]
                obs = rule.observe_scalar(scalar, episode, k)
                np.testing.assert_allclose(
                    obs, rule.observe(batched, slice(None), after)[0], rtol=1e-6, atol=1e-7
                )
                if term_s or trunc_s:
                    break
    finally:
        env.close()
    assert compared > 150 and captured >= 1
