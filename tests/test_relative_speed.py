"""The end-effector's instantaneous speed relative to the capture point, |J(theta) dtheta/dt -
Xdot_T|: ``info["relative_speed"]`` at each step's end against a finite difference of forward
kinematics; the episode columns at the capture instant (distance, relative speed, the largest
relative speed over the hold) against an independent replay; the reward's speed term (a fast pass
pays less than a slow arrival at the same distance, the sparse reward is unchanged); and the same
values in the single env, the vector env and the evaluation's records."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from test_step_rule import _side as step_rule_side

from capture_bench.agents import make_agent
from capture_bench.engine.task import CaptureTask
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv, sub_env_infos
from capture_bench.evaluation.running.rollout import run_episode
from capture_bench.sim.kinematics import HOME, arm_pose, forward_kinematics, jacobian
from capture_bench.task.rewards import REWARD_TERMS
from capture_bench.task.scenarios import load_scenario
from capture_bench.task.step_rule import BEFORE_TRACKS, ArmState, scalar_info

SEEDS = (1_000_100, 1_000_101, 1_000_102)  # validation seeds of paper
#: The capture columns are exact to this, m/s (the speed test's grid, VELOCITY_RESOLUTION, twice)
SPEED_TOLERANCE = 2e-4


def _scenario(hold: float, v_max: float | None, tolerance: float = 0.005):
    """paper's targets under a capture rule of its own (whatever the shipped defaults are)."""
    return load_scenario("paper").replace(
        capture={"hold": hold, "v_max": v_max}, capture_tolerance=tolerance
    )


#: A sweep through the target at full joint rate under eq. 20 alone, and a controller that lands
#: and tracks under the envelope held 0.2 s.
FLY_THROUGH = ("joint_intercept_uncapped", 0.0, None)
LAND_AND_HOLD = ("incremental_ik", 0.2, 0.05)


@dataclass
class Episode:
    thetas: list[np.ndarray]  # joint angles at reset and after each step, rad
    actions: list[np.ndarray]
    rewards: list[float]
    infos: list[dict]


def _play(env: CaptureEnv, agent_name: str, seed: int) -> Episode:
    """One episode of ``agent_name``, with the joint angles after each step."""
    agent = make_agent(agent_name, env)
    agent.reset()
    obs, _ = env.reset(seed=seed)
    episode = Episode([env.joint_angles], [], [], [])
    done = False
    while not done:
        action = np.asarray(agent.predict(obs)[0], dtype=float)
        obs, reward, terminated, truncated, info = env.step(action)
        episode.thetas.append(env.joint_angles)
        episode.actions.append(action)
        episode.rewards.append(reward)
        episode.infos.append(info)
        done = terminated or truncated
    return episode


def _speed(theta0, theta1, dt, s, target_velocity) -> float:
    """|J(theta(s)) dtheta/dt - Xdot_T| on a step from theta0 to theta1 (constant joint rates)."""
    delta = theta1 - theta0
    return float(np.linalg.norm(jacobian(theta0 + s * delta) @ (delta / dt) - target_velocity))


# -- info["relative_speed"] -----------------------------------------------------------------------


def test_relative_speed_is_a_finite_difference_of_forward_kinematics_minus_the_target_velocity():
    """At every step's end: (FK(theta_end) - FK a hair earlier along the same step) / time, minus
    Xdot_T(t_end). Random actions at full scale turn joint 1 by up to 0.5 rad a step, so the
    step's mean velocity (what the column was) is far from the instantaneous one."""
    env = CaptureEnv(_scenario(0.0, None, tolerance=0.001))
    rng = np.random.default_rng(0)
    mean_off = []
    try:
        env.reset(seed=SEEDS[0])
        trajectory = env.plan.trajectory
        for _ in range(40):
            theta0 = env.joint_angles
            _, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, 3))
            theta1, dt, t1 = env.joint_angles, info["dt"], info["time"]
            h = 1e-6  # of the step
            earlier = forward_kinematics(theta1 - h * (theta1 - theta0))
            finite = (forward_kinematics(theta1) - earlier) / (h * dt)
            xdot_t = trajectory.velocity(t1)
            expected = float(np.linalg.norm(finite - xdot_t))
            assert info["relative_speed"] == pytest.approx(expected, rel=1e-5, abs=1e-6)
            mean = (forward_kinematics(theta1) - forward_kinematics(theta0)) / dt - xdot_t
            mean_off.append(abs(float(np.linalg.norm(mean)) - expected))
            if terminated or truncated:
                break
    finally:
        env.close()
    assert max(mean_off) > 0.01  # the step's mean would fail this test


# -- the episode columns at the capture instant ---------------------------------------------------


@pytest.mark.parametrize(("agent", "hold", "v_max"), [FLY_THROUGH, LAND_AND_HOLD])
def test_the_capture_columns_are_the_values_at_the_capture_instant(agent, hold, v_max):
    """Replayed independently: the capture instant's fraction of the capturing step, the arm on
    its arc there, the true trajectory's position and velocity then; the largest relative speed
    over [capture - hold, capture] by a dense brute force. The evaluation's record holds the
    same values."""
    scenario = _scenario(hold, v_max)
    env = CaptureEnv(scenario)
    radius = math.sqrt(3) * scenario.capture_tolerance
    end_distances = []
    try:
        for seed in SEEDS:
            episode = _play(env, agent, seed)
            info = episode.infos[-1]
            assert info["is_success"], seed
            for earlier in episode.infos[:-1]:
                assert earlier["distance_at_capture"] is None
                assert earlier["relative_speed_at_capture"] is None
                assert earlier["relative_speed_max_over_hold"] is None
            trajectory = env.plan.trajectory
            t_c, t1, dt = info["capture_time"], info["time"], info["dt"]
            theta0, theta1 = episode.thetas[-2], episode.thetas[-1]
            s = (t_c - (t1 - dt)) / dt
            assert -1e-9 <= s <= 1 + 1e-9
            x_e = forward_kinematics(theta0 + s * (theta1 - theta0))
            distance = float(np.linalg.norm(x_e - trajectory.position(t_c)))
            assert info["distance_at_capture"] == pytest.approx(distance, abs=2e-5)
            assert info["distance_at_capture"] <= radius + 2e-5  # inside (or on) eq. 20's box
            if hold == 0.0:  # the capture is the entry: X_E - X_T on a face of the box
                offset = np.abs(x_e - trajectory.position(t_c)).max()
                assert offset == pytest.approx(scenario.capture_tolerance, abs=2e-5)
            end_distances.append((info["distance_at_capture"], info["distance"]))
            speed = _speed(theta0, theta1, dt, s, trajectory.velocity(t_c))
            at_capture = info["relative_speed_at_capture"]
            assert at_capture == pytest.approx(speed, abs=SPEED_TOLERANCE)
            largest = info["relative_speed_max_over_hold"]
            assert largest >= at_capture
            if hold == 0.0:
                assert largest == at_capture
            else:
                assert v_max is not None and largest <= v_max + SPEED_TOLERANCE
                brute = _brute_force_largest(episode, trajectory, t_c - hold, t_c)
                assert largest == pytest.approx(brute, abs=SPEED_TOLERANCE)
            record, _ = run_episode(
                env, make_agent(agent, env), agent_name=agent, scenario="paper", seed=seed
            )
            assert (
                record.distance_at_capture,
                record.relative_speed_at_capture,
                record.relative_speed_max_over_hold,
            ) == (info["distance_at_capture"], at_capture, largest)
    finally:
        env.close()
    # the step's end is not the capture instant: the end-of-step distance differs
    assert max(abs(a - b) for a, b in end_distances) > 1e-3


def _brute_force_largest(episode: Episode, trajectory, start: float, end: float) -> float:
    """The largest |J(theta) dtheta/dt - Xdot_T(t)| over [start, end] (s), 2,000 points a step
    and the ends, the target's velocity from its true trajectory. The joint rates change at
    the steps' ends, so a step that only touches the stretch there is left out."""
    largest = 0.0
    for k, info in enumerate(episode.infos):
        t1, dt = info["time"], info["dt"]
        t0 = t1 - dt
        if t1 <= start + 1e-9 or t0 >= end - 1e-9:
            continue
        theta0, theta1 = episode.thetas[k], episode.thetas[k + 1]
        lo, hi = max((start - t0) / dt, 0.0), min((end - t0) / dt, 1.0)
        for s in np.linspace(lo, hi, 2001):
            v = _speed(theta0, theta1, dt, s, trajectory.velocity(t0 + s * dt))
            largest = max(largest, v)
    return largest


# -- the reward's speed term ----------------------------------------------------------------------


class _Still:
    """A target at rest at ``position``."""

    def __init__(self, position: np.ndarray) -> None:
        self.at = position

    def position(self, t):
        return np.broadcast_to(self.at, np.shape(t) + (3,)).copy()

    def velocity(self, t):
        return np.zeros(np.shape(t) + (3,))


def _side(position: np.ndarray, time: float) -> dict[str, np.ndarray]:
    """One step's target side, (1, ...) arrays: X_T at rest at ``position``, estimated exactly,
    in view (test_step_rule's, with the target still)."""
    still = np.zeros(3)
    return step_rule_side(
        time, 0.0, position=position, velocity=still, estimate_position=position,
        estimate_velocity=still,
    )  # fmt: skip


V_MAX = 0.05  # m/s


def _one_step(
    reward: str,
    theta0: np.ndarray,
    theta1: np.ndarray,
    x_t: np.ndarray,
    v_max: float | None = V_MAX,
):
    """The step rule's reward and info for one step from theta0 to theta1 with X_T at rest (a
    hold of 0.3 s: neither step captures)."""
    rule = CaptureTask(_scenario(0.3, v_max, tolerance=0.001), reward=reward).rule
    state = ArmState.empty(1)
    rule.start(state, slice(None), x_t[None])
    state.theta[0], state.x_e[0] = theta0, forward_kinematics(theta0)
    state.distance[0] = np.linalg.norm(state.x_e[0] - x_t)
    before, after = _side(x_t, 1.0), _side(x_t, 1.05)
    out = rule.step(
        state, slice(None), {name: before[name] for name in BEFORE_TRACKS}, after,
        theta1[None], arm_pose(theta1[None]), np.array([False]), np.array([False]),
        lambda ask: np.zeros(1, dtype=bool), lambda j: _Still(x_t),
    )  # fmt: skip
    return out.reward.item(0), scalar_info(out.info)


@pytest.mark.parametrize("reward", ["dense", "shaped"])
def test_a_fast_pass_pays_less_than_a_slow_arrival_at_the_same_distance(reward):
    """Joint 1 alone moves the end-effector on a circle through X_T. Both steps start at the
    same distance from X_T (on either side of it) and end at the same point 4.5 mm past it: the
    slow one turns 0.001 rad towards X_T (9 mm/s), the fast one 0.021 rad through it (0.19 m/s).
    Everything but the speed is equal; the fast pass is charged its excess over v_max,
    0.05 m/s. Far from the target, or without a speed bound (eq. 20 alone), nothing is
    charged."""
    beta, delta = 0.01, 0.001  # rad: where the steps end past X_T, the slow step's turn
    x_t = forward_kinematics(HOME)
    end = HOME + np.array([beta, 0.0, 0.0])
    slow = _one_step(reward, end + np.array([delta, 0.0, 0.0]), end, x_t)
    fast = _one_step(reward, HOME - np.array([beta + delta, 0.0, 0.0]), end, x_t)
    (slow_reward, slow_info), (fast_reward, fast_info) = slow, fast
    assert not slow_info["is_success"] and not fast_info["is_success"]
    assert fast_info["distance"] == pytest.approx(slow_info["distance"], rel=1e-12)
    assert slow_info["relative_speed"] < V_MAX < fast_info["relative_speed"]
    assert slow_info["reward_speed"] == 0.0
    assert fast_info["reward_speed"] == pytest.approx(
        -(fast_info["relative_speed"] - V_MAX), abs=2e-3
    )  # the pass crosses X_T: closest approach ~0, weight ~1
    for term in REWARD_TERMS[reward]:
        if term != "reward_speed":
            assert fast_info[term] == pytest.approx(slow_info[term], abs=1e-12), term
    assert fast_reward < slow_reward - 0.1
    # far from the target the same speeds cost nothing
    start = HOME - np.array([beta + delta, 0.0, 0.0])
    far = forward_kinematics(HOME + np.array([0.0, -0.6, 0.6]))  # 0.27 m away
    _, far_info = _one_step(reward, start, end, far)
    assert far_info["relative_speed"] > V_MAX and far_info["reward_speed"] == 0.0
    unbounded_reward, unbounded = _one_step(reward, start, end, x_t, v_max=None)
    assert unbounded["reward_speed"] == 0.0
    assert unbounded_reward == pytest.approx(fast_reward - fast_info["reward_speed"], abs=1e-12)


def test_the_sparse_reward_is_the_capture_alone():
    """1 on the capturing step, 0 on every other, no speed term, fast or slow."""
    assert REWARD_TERMS["sparse"] == ("reward_capture",)
    x_t = forward_kinematics(HOME)
    end = HOME + np.array([0.01, 0.0, 0.0])
    reward, info = _one_step("sparse", HOME - np.array([0.011, 0.0, 0.0]), end, x_t)
    assert reward == 0.0 and "reward_speed" not in info
    env = CaptureEnv(_scenario(*FLY_THROUGH[1:]), reward="sparse")
    try:
        episode = _play(env, FLY_THROUGH[0], SEEDS[0])
    finally:
        env.close()
    assert episode.rewards == [float(info["is_success"]) for info in episode.infos]
    assert episode.rewards[-1] == 1.0


# -- the same values in the single env, the vector env and the records -----------------------------

COMPARED = (
    "relative_speed",
    "distance_at_capture",
    "relative_speed_at_capture",
    "relative_speed_max_over_hold",
    "reward_speed",
)


@pytest.mark.parametrize(("agent", "hold", "v_max"), [FLY_THROUGH, LAND_AND_HOLD])
def test_the_single_and_the_vector_env_give_the_same_values(agent, hold, v_max):
    """The single env's episodes of two seeds, their actions replayed in a vector env of two
    sub-envs (no autoreset): the relative speed, the capture columns and the speed term, step
    by step, to rounding (the single env computes X_E with ``math``)."""
    scenario = _scenario(hold, v_max)
    single = CaptureEnv(scenario, reuse_target_side=True)
    seeds = list(SEEDS[:2])
    try:
        episodes = [_play(single, agent, seed) for seed in seeds]
    finally:
        single.close()
    vector = CaptureVectorEnv(2, scenario, autoreset_mode=AutoresetMode.DISABLED)
    try:
        vector.reset(seed=seeds)
        steps = max(len(e.infos) for e in episodes)
        for t in range(steps):
            actions = np.array([e.actions[min(t, len(e.actions) - 1)] for e in episodes])
            _, rewards, *_, info = vector.step(actions)
            rows = sub_env_infos(info, 2)
            for i, episode in enumerate(episodes):
                if t >= len(episode.infos):
                    continue
                expected = episode.infos[t]
                for key in COMPARED:
                    assert rows[i][key] == pytest.approx(expected[key], rel=1e-9, abs=1e-12), (
                        i,
                        t,
                        key,
                    )
                assert rewards[i] == pytest.approx(episode.rewards[t], rel=1e-9, abs=1e-12)
    finally:
        vector.close()
    for episode in episodes:
        assert episode.infos[-1]["is_success"]
        assert episode.infos[-1]["relative_speed_at_capture"] is not None
