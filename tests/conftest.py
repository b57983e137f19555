"""Shared fixtures: environments that are always closed."""

import gymnasium as gym
import pytest

import capture_bench  # noqa: F401  (registers the environments)


@pytest.fixture
def make_env():
    """Factory for registered envs; closes every env it made."""
    made = []

    def _make(env_id="CaptureBench/Paper-v0", **kwargs):
        env = gym.make(env_id, **kwargs)
        made.append(env)
        return env

    yield _make
    for env in made:
        env.close()
