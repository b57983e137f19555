"""Acquisition: the analytic controllers' behaviour while an episode has never had an estimate,
and the rendered scenarios' filter start from three markers, in whole episodes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from capture_bench.agents.acquisition import ACQUIRE_AFTER, Acquisition
from capture_bench.agents.baselines import Hold, RandomAgent
from capture_bench.agents.incremental_ik import IncrementalIK
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.task.episode import describe_task
from capture_bench.task.observation import TaskDescription, encode_observation
from capture_bench.task.scenarios import Scenario, load_scenario

YAW = np.pi / 2
DESCRIPTION = TaskDescription(acquisition_yaw=YAW)
HOME = DESCRIPTION.arm.home


def observation(estimate: bool, theta: np.ndarray = HOME) -> np.ndarray:
    """An observation with the arm at ``theta``: the target 0.3 m off and drifting, or (no
    estimate) the end-effector position with zero velocity."""
    from capture_bench.sim.kinematics import forward_kinematics

    ee = forward_kinematics(theta)
    target = ee + [0.0, 0.3, 0.0] if estimate else ee
    velocity = [0.0, 0.01, 0.0] if estimate else [0.0, 0.0, 0.0]
    return encode_observation(target, velocity, ee, theta, 0.05, 0.05)


def test_scenarios_publish_a_yaw_only_for_the_rendered_camera() -> None:
    assert describe_task(load_scenario("paper")).acquisition_yaw is None
    for name in ("paper_rendered", "grasp_rendered"):
        # The camera looks along +y (from y = -1.2 m): the arm turns to point along +y.
        assert describe_task(load_scenario(name)).acquisition_yaw == pytest.approx(np.pi / 2)
        assert load_scenario(name).estimator.min_init_markers == 3


def test_no_yaw_no_acquisition() -> None:
    agent = IncrementalIK(TaskDescription())
    assert agent.acquisition is None
    blind = np.stack([observation(False)] * 3)
    for _ in range(5):
        action, _ = agent.predict(blind)
        np.testing.assert_array_equal(action, agent.act_batch(blind))
        np.testing.assert_allclose(action, 0.0, atol=1e-6)  # no estimate: incremental_ik holds


def test_blind_rows_swing_joint_one_after_acquire_after() -> None:
    agent = IncrementalIK(DESCRIPTION)
    rows = np.stack([observation(False), observation(True)])
    starts = np.ones(2, dtype=bool)
    for k in range(ACQUIRE_AFTER + 2):
        action, _ = agent.predict(rows, episode_start=starts if k == 0 else None)
        alone = agent.act_batch(rows)  # the controller itself is unchanged
        np.testing.assert_array_equal(action[1], alone[1])
        if k + 1 < ACQUIRE_AFTER:
            np.testing.assert_array_equal(action[0], alone[0])
        else:  # full rate toward +pi/2 (1.57 rad is more than one step of 10.3 rad/s)
            np.testing.assert_array_equal(action[0], [1.0, 0.0, 0.0])


def test_swing_stops_at_the_yaw() -> None:
    acquisition = Acquisition(DESCRIPTION)
    near = HOME + [YAW - 0.1, 0.0, 0.0]
    action = acquisition.swing(near[None])
    full_step = DESCRIPTION.arm.joint_rate_limits[0] * DESCRIPTION.control_period
    np.testing.assert_allclose(action, [[0.1 / full_step, 0.0, 0.0]], rtol=1e-6)
    np.testing.assert_array_equal(acquisition.swing((HOME + [YAW, 0, 0])[None]), 0.0)


def test_once_tracking_a_lost_estimate_is_not_acquisition() -> None:
    agent = IncrementalIK(DESCRIPTION)
    agent.predict(observation(True)[None], episode_start=np.ones(1, dtype=bool))
    for _ in range(ACQUIRE_AFTER + 2):
        action, _ = agent.predict(observation(False)[None])
        np.testing.assert_allclose(action, 0.0, atol=1e-6)
    # A new episode (episode_start, or reset) acquires again.
    agent.reset()
    actions = [agent.predict(observation(False)[None])[0] for _ in range(ACQUIRE_AFTER)]
    assert actions[-1][0, 0] == 1.0


def test_hold_and_random_do_not_acquire() -> None:
    assert Hold(DESCRIPTION).acquisition is None
    assert RandomAgent(DESCRIPTION).acquisition is None


def run(scenario: Scenario, seed: int, acquire: bool = True) -> tuple[dict, int | None]:
    """incremental_ik's episode on ``scenario`` at ``seed`` (without acquisition: the agent
    built from the description less its yaw): the last info and the first step with a valid
    estimate."""
    env = CaptureEnv(scenario)
    description = env.unwrapped.description
    if not acquire:
        description = dataclasses.replace(description, acquisition_yaw=None)
    agent = IncrementalIK(description)
    obs, info = env.reset(seed=seed)
    first, step, done = None, 0, False
    start = np.ones(1, dtype=bool)
    while not done:
        action, _ = agent.predict(obs, episode_start=start)
        start = np.zeros(1, dtype=bool)
        obs, _, terminated, truncated, info = env.step(action)
        step += 1
        if first is None and info["estimator_status"] in ("ok", "predicting"):
            first = step
        done = terminated or truncated
    env.close()
    return info, first


# Validation seeds of grasp_rendered whose first frames lack markers (the arm at home hides them):
# 8000108 shows three of four (the filter starts from P3P), 8000117 two (acquisition reveals the
# others). Found with scripts/three_point_start.py --scenario grasp_rendered --seeds 30.
def test_three_markers_start_the_filter() -> None:
    shipped = load_scenario("grasp_rendered")
    seed = 8000108
    assert seed in shipped.validation_seeds
    info, first = run(shipped, seed, acquire=False)
    truth, _ = run(shipped.replace(estimator={"source": "truth"}), seed, acquire=False)
    assert first == 1
    assert truth["is_success"] and info["is_success"], info["failure"]
    # Photogrammetry alone (four markers): the filter never starts, the episode is lost.
    lost, never = run(shipped.replace(estimator={"min_init_markers": 4}), seed, acquire=False)
    assert never is None and lost["failure"] == "target_lost"


def test_acquisition_reveals_the_markers() -> None:
    shipped = load_scenario("grasp_rendered")
    seed = 8000117
    info, first = run(shipped, seed)
    truth, _ = run(shipped.replace(estimator={"source": "truth"}), seed)
    assert first is not None and first <= 4
    assert truth["is_success"] and info["is_success"], info["failure"]
    # Waiting at home instead: two markers hidden throughout, the episode is lost.
    lost, never = run(shipped, seed, acquire=False)
    assert never is None and lost["failure"] == "target_lost"
