"""The reward modes (capture_bench/task/rewards.py): the shaped mode is potential-based shaping,
F = gamma Phi(d') - Phi(d) (Ng, Harada & Russell 1999), so over an episode its discounted sum
telescopes to gamma**T Phi(d_T) - Phi(d_0); and it is the dense reward with only its progress
term replaced."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.task.rewards import (
    REWARD_TERMS,
    SHAPING_GAMMA,
    SHAPING_LENGTH,
    potential,
    reward_terms,
)


def _episode(env: CaptureEnv, seed: int, agent_name: str) -> tuple[list[float], list[dict]]:
    """One episode with ``agent_name``: the true distance at reset and after each step, and
    each step's info."""
    from capture_bench.agents import make_agent

    agent = make_agent(agent_name, env)
    obs, info = env.reset(seed=seed)
    distances, infos = [info["distance"]], []
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(agent.predict(obs)[0])
        distances.append(info["distance"])
        infos.append(info)
        done = terminated or truncated
    return distances, infos


@pytest.mark.parametrize(("seed", "agent"), [(3, "incremental_ik"), (4, "random")])
def test_the_shaping_term_telescopes_over_an_episode(seed, agent):
    env = CaptureEnv("paper", reward="shaped")
    try:
        distances, infos = _episode(env, seed, agent)
    finally:
        env.close()
    shaping = [info["reward_shaping"] for info in infos]
    T = len(shaping)
    discounted = sum(SHAPING_GAMMA**t * f for t, f in enumerate(shaping))
    expected = SHAPING_GAMMA**T * potential(distances[-1]) - potential(distances[0])
    assert discounted == pytest.approx(expected, rel=1e-9, abs=1e-12)
    if agent == "incremental_ik":
        assert infos[-1]["is_success"]  # a captured episode: the sum reaches near Phi(0) = 0


def test_the_shaped_reward_is_dense_with_its_progress_term_replaced():
    d0, d1 = np.array([0.3, 0.002, 0.001]), np.array([0.2, 0.001, 0.0015])
    captured, penalised = np.array([False, True, False]), np.array([False, False, True])
    dense = reward_terms("dense", d0, d1, captured, penalised)
    shaped = reward_terms("shaped", d0, d1, captured, penalised)
    assert list(shaped) == list(REWARD_TERMS["shaped"])
    for term in ("reward_time", "reward_capture", "reward_failure"):
        np.testing.assert_array_equal(shaped[term], dense[term])
    np.testing.assert_allclose(
        shaped["reward_shaping"], SHAPING_GAMMA * potential(d1) - potential(d0)
    )
    # the last millimetre is worth as much as a first decimetre (dense: 100 times less)
    assert shaped["reward_shaping"][1] == pytest.approx(shaped["reward_shaping"][0], rel=0.2)
    assert dense["reward_progress"][1] == pytest.approx(dense["reward_progress"][0] / 100)


def test_the_potential_is_a_log_distance_in_both_forms():
    for d in (0.0, 1e-4, SHAPING_LENGTH, 0.5):
        assert potential(d) == pytest.approx(-math.log(1 + d / SHAPING_LENGTH), rel=1e-12)
        assert isinstance(potential(d), float)  # the single env's path stays in Python floats
        assert potential(np.array([d]))[0] == pytest.approx(potential(d), rel=1e-15)
    assert potential(0.0) == 0.0
