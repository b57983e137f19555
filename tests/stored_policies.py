"""A check shared by the tests of stored policies."""

from __future__ import annotations

import numpy as np

from capture_bench.agents.sb3_policy import SB3Policy, load_policy, load_trusted, read_metadata
from capture_bench.envs.capture_env import CaptureEnv


def assert_loads_safely_and_acts_as_trusted(run, steps: int = 3) -> None:
    """The policy stored in ``run`` loads without unpickling, and for ``steps`` steps of an
    episode of its env acts exactly as the same policy loaded by SB3 (trusted)."""
    metadata = read_metadata(run)
    safe, trusted = load_policy(metadata), load_trusted(metadata)
    with CaptureEnv("paper", **metadata.env_options) as env:
        obs, _ = env.reset(seed=5)
        for _ in range(steps):
            a = SB3Policy(safe.policy).predict(obs)[0]
            np.testing.assert_array_equal(a, SB3Policy(trusted.policy).predict(obs)[0])
            obs = env.step(a)[0]


def assert_evaluates_in_pixel_envs(run, out) -> None:
    """``evaluate.py`` plays the model in ``run`` (a directory named ``run``) on two episodes of
    ``paper`` into ``out``, its row labelled as a pixel policy's."""
    import evaluate

    argv = ["--agents", str(run), "--scenarios", "paper", "--episodes", "2", "--workers", "1"]
    assert evaluate.main([*argv, "--out", str(out)]) == 0
    rows = next(out.rglob("episodes.csv")).read_text().splitlines()
    assert sum(row.startswith("run (pixels),paper,") for row in rows) == 2
