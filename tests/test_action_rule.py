"""The leaderboard's rule for trained policies (issue 14 point 5): deterministic actions, unless
the model card declares ``actions: sampled``; then actions are sampled, seeded per episode so a
run stays reproducible, and the row says so."""

from __future__ import annotations

import json

import numpy as np
import pytest
from stand_in import sb3_model

from capture_bench.agents.policy_file import PolicyLoadError, save_policy
from capture_bench.agents.sb3_policy import read_metadata
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.evaluation.running.agents_loading import build_agent, resolve_agent


def _model(tmp_path, actions=None):
    model, _ = sb3_model("PPO", learn=64)
    extra = {"scenario": "paper"} | ({"actions": actions} if actions else {})
    save_policy(tmp_path / "m", "PPO", model.policy, extra=extra)
    return tmp_path / "m"


def _actions(spec, env, seed, n=5):
    agent = build_agent(spec, env, seed=seed)
    obs, _ = env.reset(seed=1000100)
    return np.stack([agent.predict(obs)[0] for _ in range(n)])


def test_sampled_actions_are_declared_seeded_per_episode_and_labelled(tmp_path):
    spec = resolve_agent(str(_model(tmp_path, "sampled")))
    assert spec.label == "m (sampled)"
    env = CaptureEnv("paper")
    try:
        first, again, other = (_actions(spec, env, s) for s in (7, 7, 8))
        np.testing.assert_array_equal(first, again)  # reproducible per episode seed
        assert not np.array_equal(first, other)
        assert len({tuple(a) for a in first}) > 1  # sampled: not one action repeated
    finally:
        env.close()


def test_the_default_is_deterministic_and_unlabelled(tmp_path):
    spec = resolve_agent(str(_model(tmp_path)))
    assert spec.label == "m" and read_metadata(spec.target).actions == "deterministic"
    env = CaptureEnv("paper")
    try:
        first = _actions(spec, env, 7)
        assert len({tuple(a) for a in first}) == 1
        np.testing.assert_array_equal(first, _actions(spec, env, 8))
    finally:
        env.close()


def test_a_bad_action_rule_is_one_clear_error(tmp_path):
    directory = _model(tmp_path)
    meta = json.loads((directory / "metadata.json").read_text())
    (directory / "metadata.json").write_text(json.dumps(meta | {"actions": "greedy"}))
    with pytest.raises(PolicyLoadError, match="key 'actions' is 'greedy'; valid: deterministic"):
        read_metadata(directory)
