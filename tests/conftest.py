"""Shared fixtures: environments that are always closed."""

import tempfile
from pathlib import Path

import gymnasium as gym
import pytest
from hypothesis.configuration import set_hypothesis_home_dir

import capture_bench  # noqa: F401  (registers the environments)

# The fuzz tests use no example database (CI sees the same inputs every run); Hypothesis's own
# caches (constants, Unicode tables) go to the temporary folder, not a .hypothesis/ in the checkout.
set_hypothesis_home_dir(Path(tempfile.gettempdir()) / "capture-bench-hypothesis")


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
