"""The step rule's defined sets, exposed exactly by both envs; the rule at one episode (as the
single env runs it) against hand-computed steps; an episode's numbers the same alone or in a
batch; the observation and the estimate's errors against hand values, and the errors' one-estimate
fast path against their batched form; the episode cache's public interface."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import capture_bench  # noqa: F401  (registers the envs)
from capture_bench.engine.cache import EpisodeCache
from capture_bench.engine.task import CaptureTask
from capture_bench.envs import capture_env
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.evaluation.reporting.aggregate import KNOWN_FAILURES
from capture_bench.sensing.estimator import STATUSES
from capture_bench.sim import kinematics
from capture_bench.task.observation import encode_observation
from capture_bench.task.recording import STEP_TRACKS, estimate_errors
from capture_bench.task.rewards import REWARD_MODES, REWARD_TERMS
from capture_bench.task.step_rule import (
    BEFORE_TRACKS,
    END_INFO_KEYS,
    FAILURE_NAMES,
    FAILURES,
    INFO_KEYS,
    RESET_INFO_KEYS,
    ArmState,
    info_keys,
    scalar_info,
)


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


def test_an_env_given_its_own_episode_cache_keeps_recordings_there_and_clear_empties_it():
    cache = EpisodeCache()
    env = gym.make("CaptureBench/Paper-v1", reuse_target_side=True, episode_cache=cache)
    try:
        env.reset(seed=4)
        key = (env.unwrapped.scenario, 4)
        assert cache.recorded_keys() == [key]
        episode, _state = cache.recording(key)
        assert env.unwrapped.recorded_episode is episode
        limit = env.unwrapped.physical_limit()
        assert episode.bound is limit  # kept with the recording
        cache.clear()
        assert cache.recorded_keys() == [] and cache.limit(key) is None
        env.reset(seed=4)  # recorded again: the same episode, a new object
        again = env.unwrapped.recorded_episode
        assert again is not episode
        np.testing.assert_array_equal(again.estimate_position, episode.estimate_position)
    finally:
        env.close()


# -- the rule at one episode, against hand-computed steps ---------------------------------------

X_E = kinematics.forward_kinematics(kinematics.HOME)  # the arm holds still at home
_OK, _DIVERGED = STATUSES.index("ok"), STATUSES.index("diverged")


def _side(time: float, offset_mm: float, **tracks) -> dict[str, np.ndarray]:
    """One step's target side as (1, ...) arrays: X_T = X_E + (offset_mm, 0, 0) mm, moving at
    -0.2 m/s along x, the estimate exact, every frame usable, in reach."""
    position = X_E + np.array([offset_mm * 1e-3, 0.0, 0.0])
    values = {
        "time": time,
        "dt": 0.05,
        "position": position,
        "velocity": np.array([-0.2, 0.0, 0.0]),
        "estimate_position": position,
        "estimate_velocity": np.array([-0.2, 0.0, 0.0]),
        "estimate_valid": True,
        "estimator_status": _OK,
        "visible": True,
        "reachable": True,
        "position_error": 0.0,
        "velocity_error": 0.0,
        "nees": math.nan,
        **tracks,
    }
    assert set(values) == set(STEP_TRACKS)
    return {name: np.array([value]) for name, value in values.items()}


class _Arm:
    """One episode under the rule with the arm still at home; records the collision queries.
    The rule is the paper's eq. 20 as published (paper_eq20: 1 mm, any speed, no hold) unless
    the test asks for another."""

    def __init__(self, scenario: str = "paper_eq20", start_mm: float = 5.0, hold: float = 0.0):
        self.rule = CaptureTask(scenario).rule
        self.rule.set_hold(hold)
        self.state = ArmState.empty(1)
        self.before = _side(1.0, start_mm)
        self.rule.start(self.state, slice(None), self.before["position"])
        self.asked: list[bool] = []

    def step(self, after: dict[str, np.ndarray], collision: bool = False) -> tuple:
        def collides(ask: np.ndarray) -> np.ndarray:
            self.asked.append(bool(ask[0]))
            return ask & collision

        def trajectory(j: int):
            raise AssertionError("a still arm has no arc to walk")

        theta = kinematics.HOME[None].copy()
        before = {name: self.before[name] for name in BEFORE_TRACKS}
        out = self.rule.step(
            self.state, slice(None), before, after, theta, kinematics.arm_pose(theta), np.array([False]),
            np.array([False]), collides, trajectory,
        )  # fmt: skip
        self.before = after
        info = scalar_info(out.info)
        return out.reward.item(0), bool(out.terminated[0]), bool(out.truncated[0]), info


def test_a_pass_through_the_box_mid_step_captures_at_the_entry():
    """X_T passes from +5 mm to -5 mm along x in a step of 0.05 s from t = 1 s: X_E - X_T enters
    the 1 mm box at s = 0.4, so the capture (eq. 20, no hold) is at 1.02 s, on the estimate too;
    collisions are not asked about on a capture."""
    arm = _Arm()
    reward, terminated, truncated, info = arm.step(_side(1.05, -5.0), collision=True)
    assert info["is_success"] and terminated and not truncated and info["failure"] is None
    assert info["capture_time"] == pytest.approx(1.02, abs=1e-12)
    assert info["capture_time_estimated"] == pytest.approx(1.02, abs=1e-12)
    assert arm.asked == [False]
    assert info["distance"] == pytest.approx(5e-3) and info["path_length"] == 0.0
    assert info["relative_speed"] == pytest.approx(0.2)  # X_E still, X_T at 0.2 m/s
    terms = {"reward_progress": 0.0, "reward_time": -0.01, "reward_capture": 5.0,
             "reward_failure": 0.0}  # fmt: skip
    assert {k: info[k] for k in terms} == pytest.approx(terms, abs=1e-15)
    assert reward == pytest.approx(4.99)
    assert (info["time"], info["dt"], info["estimator_status"]) == (1.05, 0.05, "ok")


def test_a_hold_needs_the_stay_to_last_and_carries_it_across_steps():
    """With a 0.03 s hold the 0.01 s pass is not a capture; then X_T comes back to X_E (entry at
    s = 0.8 of the next step, 1.09 s) and stays: the capture completes at 1.09 + 0.03 s."""
    arm = _Arm(hold=0.03)
    _, terminated, _, info = arm.step(_side(1.05, -5.0))
    assert not terminated and info["capture_time"] is None and info["failure"] is None
    _, terminated, _, info = arm.step(_side(1.10, 0.0))
    assert not terminated and info["capture_time"] is None
    reward, terminated, _, info = arm.step(_side(1.15, 0.0))
    assert terminated and info["is_success"]
    assert info["capture_time"] == pytest.approx(1.12, abs=1e-12)
    assert info["capture_time_estimated"] == pytest.approx(1.12, abs=1e-12)


def test_the_failures_in_their_order_and_their_rewards():
    # collision: -5, terminated
    arm = _Arm(start_mm=50.0)
    reward, terminated, truncated, info = arm.step(_side(1.05, 40.0), collision=True)
    assert (terminated, truncated, info["failure"], arm.asked) == (True, False, "collision", [True])
    assert info["reward_failure"] == -5.0
    assert info["reward_progress"] == pytest.approx(10 * 0.01)
    assert reward == pytest.approx(0.1 - 0.01 - 5.0)
    # unreachable once X_T has been out of reach for more than lost_after; collision comes first
    for collision, expected in ((False, "unreachable"), (True, "collision")):
        arm = _Arm(start_mm=50.0)
        arm.state.unreachable_for[:] = arm.rule.lost_after - 0.01
        *_, info = arm.step(_side(1.05, 50.0, reachable=False), collision=collision)
        assert info["failure"] == expected
    arm = _Arm(start_mm=50.0)
    arm.state.unreachable_for[:] = arm.rule.lost_after
    *_, info = arm.step(_side(1.05, 50.0))  # back in reach: the clock restarts
    assert info["failure"] is None and arm.state.unreachable_for[0] == 0.0
    # target_lost without a usable frame for more than lost_after (never with the truth source)
    for scenario, expected in (("paper_eq20", "target_lost"), ("paper_eq20", None)):
        arm = _Arm(scenario, start_mm=50.0)
        if expected is None:
            arm.rule = CaptureTask(scenario, observation_source="truth").rule
        arm.state.since_frame[:] = arm.rule.lost_after - 0.01
        status = {"estimator_status": _DIVERGED, "estimate_valid": False}
        reward, terminated, _, info = arm.step(_side(1.05, 50.0, **status))
        assert info["failure"] == expected and terminated == (expected is not None)
        assert info["estimator_status"] == "diverged"
    # timeout at the time limit: a truncation, not penalised
    arm = _Arm(start_mm=50.0)
    limit = float(arm.rule.time_limit)
    reward, terminated, truncated, info = arm.step(_side(limit, 50.0))
    assert (terminated, truncated, info["failure"]) == (False, True, "timeout")
    assert info["reward_failure"] == 0.0 and reward == pytest.approx(-0.01)


# -- an episode alone (N = 1, the single env) or in a batch: the same numbers -------------------


def _episode_rows(episodes, k, names=STEP_TRACKS):
    """Step k of each episode's tracks, stacked: (M, ...) arrays."""
    return {n: np.stack([getattr(e, n)[k] for e in episodes]) for n in names}


@pytest.mark.parametrize(("scenario", "reward"), [("paper", "dense"), ("grasp", "shaped")])
def test_an_episode_gets_the_same_numbers_alone_or_in_a_batch(scenario, reward):
    """StepRule.step over three recorded episodes at once, and over each alone (N = 1, as the
    single env runs it), with arms that close on the target (captures, along the arc) or swing
    away (collisions): every info value, reward and end, float for float, to each episode's end
    (the batch shrinks as episodes end)."""
    from capture_bench.agents import make_agent
    from capture_bench.sim.world import limit_joint_increments

    env = CaptureEnv(scenario, reward=reward, reuse_target_side=True)
    rule, arm = env.rule, env.description.arm
    episodes = []
    for seed in (3, 4, 5):
        env.reset(seed=seed)
        episodes.append(env.recorded_episode)
    env.close()
    agents = [make_agent("incremental_ik", env) for _ in episodes]
    m = len(episodes)
    batch, alone = ArmState.empty(m), [ArmState.empty(1) for _ in episodes]
    rule.start(batch, np.arange(m), _episode_rows(episodes, 0)["position"])
    for state, episode in zip(alone, episodes, strict=True):
        rule.start(state, slice(None), episode.position[:1])
    going, ends = list(range(m)), []
    for k in range(1, episodes[0].time.size):
        rows = np.array(going)
        playing = [episodes[i] for i in going]
        obs = rule.observe(batch, rows, _episode_rows(playing, k - 1))
        actions = []
        for i, o in zip(going, obs, strict=True):
            swing = i == 1 and k > 8  # IK first, then into the floor
            actions.append([1.0, -1.0, -1.0] if swing else agents[i].predict(o)[0])
        request = env.description.action_to_increment(np.clip(actions, -1, 1))
        dt = _episode_rows(playing, k, ("dt",))["dt"]
        theta, clipped, saturated = limit_joint_increments(batch.theta[rows], request, dt, arm)
        pose = kinematics.arm_pose(theta)
        x_e = pose.x_e

        def collides(ask, x_e=x_e):
            return ask & (x_e[:, 2] < 0.05)

        out = rule.step(
            batch, rows, _episode_rows(playing, k - 1, BEFORE_TRACKS), _episode_rows(playing, k),
            theta, pose, clipped, saturated, collides, lambda j, p=playing: p[j].plan.trajectory,
        )  # fmt: skip
        for j, i in enumerate(going):
            one = rule.step(
                alone[i], slice(None), episodes[i].rows(k - 1, BEFORE_TRACKS), episodes[i].rows(k),
                theta[j : j + 1], pose.take(slice(j, j + 1)), clipped[j : j + 1], saturated[j : j + 1],
                lambda ask, j=j, x_e=x_e: ask & (x_e[j : j + 1, 2] < 0.05),
                lambda _, e=episodes[i]: e.plan.trajectory,
            )  # fmt: skip
            assert _same(scalar_info(one.info), scalar_info(out.info, j)), (k, i)
            assert one.reward.item(0) == out.reward.item(j)
            assert (one.terminated[0], one.truncated[0]) == (out.terminated[j], out.truncated[j])
        done = out.terminated | out.truncated
        for j in np.flatnonzero(done).tolist():
            ends.append(scalar_info(out.info, j))
        going = [i for j, i in enumerate(going) if not done[j]]
        if not going:
            break
    assert sum(info["is_success"] for info in ends) >= 1
    assert any(info["failure"] == "collision" for info in ends)


def _same(a: dict, b: dict) -> bool:
    """Equal, NaN equal to NaN."""
    return a.keys() == b.keys() and all(
        x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))
        for x, y in zip(a.values(), b.values(), strict=True)
    )


# -- the observation and the estimate's errors ---------------------------------------------------


def test_the_observation_is_scaled_as_documented_and_a_batch_is_its_rows():
    obs = encode_observation(
        [0.1, 0.2, 0.3], [0.01, 0.0, 0.0], [0.4, 0.0, 0.45], [0.0, np.pi / 2, 0.0], 0.06, 0.05
    )
    relative = (np.array([0.1, 0.2, 0.3]) + np.array([0.01, 0, 0]) * 0.05 - [0.4, 0.0, 0.45]) / 0.5
    expected = [0.1, 0.2, 0.3, 0.1, 0.0, 0.0, 0.4, 0.0, 0.45, 0.0, 0.5, 0.0, *relative, 1.2]
    assert obs.shape == (16,) and obs.dtype == np.float32
    np.testing.assert_allclose(obs, expected, rtol=1e-6, atol=1e-7)
    clipped = encode_observation([50.0, 0, 0], [-5.0, 0, 0], [0.0, 0, 0], [0.0, 0, 0], 0.05, 0.05)
    assert clipped[0] == 10.0 and clipped[3] == -10.0 and clipped[12] == 10.0
    rng = np.random.default_rng(3)
    rows = [rng.normal(0, 0.3, (50, 3)) for _ in range(4)]
    periods = rng.uniform(0.04, 0.06, 50)
    batch = encode_observation(*rows, periods, 0.05)
    assert batch.shape == (50, 16)
    for i in range(50):
        np.testing.assert_array_equal(
            batch[i], encode_observation(*(r[i] for r in rows), periods[i], 0.05)
        )


def test_estimate_errors_equal_the_scalar_reference_and_each_row_alone():
    from references.scalar_estimator import TargetEstimate, estimate_errors_scalar

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
        row = slice(k, k + 1)
        alone = estimate_errors(
            pos[row], vel[row], cov[row], valid[row], true_pos[row], true_vel[row]
        )
        np.testing.assert_array_equal([a[0] for a in alone], [b[k] for b in batched])


def test_estimate_errors_against_hand_values_and_row_by_row():
    """Errors are distances; the NEES is e' P^-1 e (a diagonal P by hand, others by a solve);
    NaN without a valid estimate, without a covariance, or with one not positive definite; and
    each row alone gives the batch's floats."""
    rng = np.random.default_rng(3)
    n = 40
    true_pos, true_vel = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    pos = true_pos + 0.01 * rng.normal(size=(n, 3))
    vel = true_vel + 0.1 * rng.normal(size=(n, 3))
    pos[0], vel[0] = true_pos[0] + [0.01, 0.02, 0.02], true_vel[0] + [0.0, 0.03, 0.04]
    a = rng.normal(size=(n, 6, 6))
    cov = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(6)
    sigma = np.array([0.01, 0.02, 0.03, 0.1, 0.2, 0.3])
    cov[0] = np.diag(sigma**2)
    cov[5] = -np.eye(6)  # not positive definite
    cov[6] = np.nan  # no covariance
    valid = np.ones(n, dtype=bool)
    valid[7] = False
    pos[7] = vel[7] = np.nan  # no estimate
    position_error, velocity_error, nees = estimate_errors(pos, vel, cov, valid, true_pos, true_vel)
    assert position_error[0] == pytest.approx(0.03) and velocity_error[0] == pytest.approx(0.05)
    e0 = np.array([0.01, 0.02, 0.02, 0.0, 0.03, 0.04])
    assert nees[0] == pytest.approx(((e0 / sigma) ** 2).sum(), rel=1e-12)
    for k in range(8, n):
        e = np.concatenate([pos[k] - true_pos[k], vel[k] - true_vel[k]])
        assert nees[k] == pytest.approx(e @ np.linalg.solve(cov[k], e), rel=1e-9)
    assert np.isnan(nees[[5, 6, 7]]).all() and np.isfinite(nees[[0, 1, 2, 3, 4]]).all()
    assert np.isnan(position_error[7]) and np.isnan(velocity_error[7])
    # Rows 8.. in one batched factorisation, each row alone: the same floats.
    batch = estimate_errors(pos[8:], vel[8:], cov[8:], valid[8:], true_pos[8:], true_vel[8:])
    for k in range(8, n):
        row = slice(k, k + 1)
        alone = estimate_errors(pos[row], vel[row], cov[row], valid[row], true_pos[row],
                                true_vel[row])  # fmt: skip
        np.testing.assert_array_equal([x[0] for x in alone], [x[k - 8] for x in batch])
    np.testing.assert_array_equal(batch[2], nees[8:])
