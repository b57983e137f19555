"""Tests of planned_intercept: the oracle's landing and tracking on the estimate, never the truth."""

import gymnasium
import numpy as np
import pytest

from capture_bench.agents import IncrementalIK, PlannedIntercept, make_agent
from capture_bench.sim.kinematics import HOME, forward_kinematics
from capture_bench.task.observation import TaskDescription, encode_observation
from capture_bench.task.scenarios import load_scenario

PAPER = load_scenario("paper")


class Touched(AssertionError):
    pass


class PublicOnly:
    """An env handle whose ``unwrapped`` has the public description and nothing else: any other
    attribute (``physical_limit``, ``plan``, ``true_target_position``, ``time``...) raises."""

    class _Guard:
        def __init__(self, description: TaskDescription) -> None:
            object.__setattr__(self, "description", description)

        def __getattr__(self, name: str):
            raise Touched(f"agent read env.unwrapped.{name}")

    def __init__(self, env) -> None:
        self._guard = self._Guard(env.unwrapped.description)

    @property
    def unwrapped(self):
        return self._guard


def play(env, agent, seed: int) -> dict:
    """One episode, ``episode_start`` on its first step; the last info."""
    observation, info = env.reset(seed=seed)
    agent.reset()
    first = True
    while True:
        action, _ = agent.predict(observation, episode_start=np.array([first]))
        first = False
        assert action.shape == (3,) and action.dtype == np.float32
        assert np.all(np.isfinite(action)) and np.all(np.abs(action) <= 1.0)
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return info


@pytest.fixture
def paper_env():
    env = gymnasium.make(PAPER.env_id, observation_source="ekf")
    yield env
    env.close()


def test_it_captures_validation_episodes_on_the_estimate_without_the_privileged_api(paper_env):
    agent = make_agent("planned_intercept", PublicOnly(paper_env))
    assert not agent.privileged and agent.batched
    for seed in PAPER.validation_seeds[:3]:
        info = play(paper_env, agent, seed)
        assert info["is_success"], (seed, info["failure"])
        assert info["capture_time"] <= 1.15 * info["physical_limit_time"], (seed, info)
    assert agent.planned >= 3


def test_on_the_true_state_it_is_within_a_few_percent_of_the_oracle():
    env = gymnasium.make(PAPER.env_id, observation_source="truth")
    try:
        seed = PAPER.validation_seeds[0]
        oracle = play(env, make_agent("oracle", env), seed)
        planned = play(env, make_agent("planned_intercept", PublicOnly(env)), seed)
    finally:
        env.close()
    assert oracle["is_success"] and planned["is_success"]
    assert planned["capture_time"] <= 1.03 * oracle["capture_time"], (planned, oracle)


def observe(theta, position, velocity):
    return encode_observation(position, velocity, forward_kinematics(theta), theta, 0.05, 0.05)


def test_without_a_valid_estimate_it_takes_the_incremental_ik_step():
    """The env reports no estimate as X_E with zero velocity; the paper's controller's step."""
    description = TaskDescription()
    agent, paper = PlannedIntercept(description), IncrementalIK(description)
    obs = observe(HOME, forward_kinematics(HOME), np.zeros(3))
    assert np.array_equal(agent.predict(obs)[0], paper.predict(obs)[0])
    assert agent.planned == 0


def test_an_unchanged_observation_gets_the_same_action_without_a_new_plan():
    """An ended episode's row, frozen in a batch, costs nothing after its first step."""
    description = TaskDescription()
    agent = PlannedIntercept(description)
    target = forward_kinematics(HOME + [0.4, -0.3, 0.3])  # reachable
    obs = np.stack([observe(HOME, target, [0.01, 0.0, 0.0])] * 2)
    first, _ = agent.predict(obs, episode_start=np.ones(2, bool))
    planned = agent.planned
    again, _ = agent.predict(obs)
    assert np.array_equal(first, again) and agent.planned == planned
    assert np.array_equal(first[0], first[1])  # rows of a batch are planned as alone


def test_episode_start_forgets_the_plan():
    agent = PlannedIntercept(TaskDescription())
    obs = observe(HOME, forward_kinematics(HOME + [0.4, -0.3, 0.3]), [0.01, 0.0, 0.0])
    agent.predict(obs)
    assert agent.plans[0] is not None and not agent.plans[0].fallback
    agent.predict(obs, episode_start=np.array([True]))
    assert agent.planned == 2


def test_joints_that_jumped_further_than_a_step_mean_a_new_plan():
    """A new episode in an auto-resetting env: the arm is back home, which no action does."""
    agent = PlannedIntercept(TaskDescription())
    target = forward_kinematics(HOME + [0.4, -0.3, 0.3])
    agent.predict(observe(HOME, target, [0.01, 0.0, 0.0]))
    assert agent.planned == 1
    away = HOME + [0.3, -0.2, 0.2]  # further than one step of every joint
    agent.predict(observe(away, target, [0.01, 0.0, 0.0]))
    assert agent.planned == 2


def test_without_kept_plans_the_action_is_a_function_of_the_observation(paper_env):
    """keep_plans=False: on every state of an episode (driven by the planning agent), the action
    is a new agent's first action on that state alone; the planning agent's differs somewhere."""
    fresh = PlannedIntercept(paper_env.unwrapped.description, keep_plans=False)
    kept = PlannedIntercept(paper_env.unwrapped.description)
    observation, _ = paper_env.reset(seed=PAPER.validation_seeds[0])
    differ = 0
    for step in range(40):
        action, _ = kept.predict(observation, episode_start=np.array([step == 0]))
        alone, _ = PlannedIntercept(paper_env.unwrapped.description).predict(observation)
        assert np.array_equal(fresh.predict(observation)[0], alone)
        differ += not np.array_equal(action, alone)
        observation, _, terminated, truncated, _ = paper_env.step(action)
        if terminated or truncated:
            break
    assert differ > 0
