"""The hybrid (issue 14 point 6): a learned residual on an analytic controller,
a = clip(a_base(s) + alpha pi(s)). The sum is the same in training (ResidualVecEnv), in the
training-time validation and in evaluation (ResidualAgent from the model's metadata)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import train
from capture_bench.agents import make_agent
from capture_bench.agents.residual import RESIDUAL_BASES, ResidualAgent, combine, make_base
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.task.scenarios import load_scenario


class Constant:
    """A 'learned' policy that always proposes the same residual."""

    def __init__(self, value):
        self.value = np.asarray(value, dtype=np.float32)

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(observation)
        shape = (obs.shape[0], 3) if obs.ndim == 2 else (3,)
        return np.broadcast_to(self.value, shape).copy(), state


def test_combine_adds_the_scaled_residual_and_clips():
    out = combine(np.array([0.5, -0.9, 0.0]), np.array([1.0, -1.0, np.nan]), 0.4)
    np.testing.assert_allclose(out, [0.9, -1.0, 0.0], rtol=1e-6)
    assert out.dtype == np.float32


def test_a_zero_residual_is_the_base_controller_and_batches_agree():
    env = CaptureEnv("paper")
    try:
        obs, _ = env.reset(seed=load_scenario("paper").validation_seeds[0])
        base = make_agent("incremental_ik", env)
        agent = ResidualAgent(make_base("incremental_ik", env.description), Constant(0.0), 0.5)
        np.testing.assert_array_equal(agent.predict(obs)[0], base.predict(obs)[0])
        batch = np.stack([obs, obs * 0.9])
        nudged = ResidualAgent(base, Constant([0.2, -0.2, 0.1]), 0.5)
        np.testing.assert_array_equal(
            nudged.predict(batch)[0], np.stack([nudged.predict(o)[0] for o in batch])
        )
    finally:
        env.close()
    with pytest.raises(ValueError, match="analytic controller 'oracle'"):
        make_base("oracle", env.description)


def test_the_training_envs_step_with_the_base_plus_the_scaled_residual():
    from capture_bench.training.common.residual_vec_env import ResidualVecEnv
    from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

    scale, residual = 0.3, np.array([[0.5, -0.5, 0.2], [-1.0, 1.0, 0.0]], np.float32)
    plain = CaptureSB3VecEnv(2, "paper", seed=4)
    wrapped = ResidualVecEnv(CaptureSB3VecEnv(2, "paper", seed=4), "incremental_ik", scale,
                             plain.venv.description)  # fmt: skip
    base = make_base("incremental_ik", plain.venv.description)
    try:
        obs_plain, obs_wrapped = plain.reset(), wrapped.reset()
        for _ in range(60):  # across the end of some episodes (same-step resets)
            np.testing.assert_array_equal(obs_plain, obs_wrapped)
            plain.step_async(combine(base.predict(obs_plain)[0], residual, scale))
            wrapped.step_async(residual)
            obs_plain, r1, d1, _ = plain.step_wait()
            obs_wrapped, r2, d2, _ = wrapped.step_wait()
            np.testing.assert_array_equal(r1, r2)
            np.testing.assert_array_equal(d1, d2)
    finally:
        plain.close()
        wrapped.close()


@pytest.fixture(scope="module")
def residual_run(tmp_path_factory):
    """A tiny PPO residual on incremental_ik (scale 0.05, so the hybrid is nearly the base),
    validated on 4 validation seeds."""
    root = tmp_path_factory.mktemp("residual")
    sets = ["residual=incremental_ik", "residual_scale=0.05", "n_envs=2", "n_steps=32",
            "batch_size=32", "n_epochs=1", "policy_kwargs.net_arch=[8]", "total_timesteps=128",
            "eval_freq=64", "eval_episodes=4"]  # fmt: skip
    argv = [f"--set={s}" for s in sets]
    root.joinpath("cwd").mkdir()
    import os

    cwd = os.getcwd()
    os.chdir(root / "cwd")  # the default run directory lands here
    try:
        assert train.main(["--algo", "ppo", *argv]) == 0
    finally:
        os.chdir(cwd)
    (run_dir,) = (root / "cwd" / "runs").iterdir()
    return run_dir


def test_a_residual_run_is_named_declared_and_validated_as_the_hybrid(residual_run):
    assert residual_run.name == "paper-ppo-residual-0"
    meta = json.loads((residual_run / "metadata.json").read_text())
    assert meta["residual"] == {"base": "incremental_ik", "scale": 0.05}
    validation = json.loads((residual_run / "best" / "validation.json").read_text())
    # an untrained residual at 5%: the validation is the paper controller's (which captures
    # all four of these seeds); a validation that forgot the base would capture none
    assert validation["validation"]["capture_rate"] == 1.0, validation


def test_evaluation_rebuilds_the_hybrid_from_the_metadata(residual_run):
    from capture_bench.agents.sb3_policy import SB3Policy, load_sb3_policy
    from capture_bench.evaluation.running.agents_loading import build_agent, resolve_agent

    env = CaptureEnv("paper")
    try:
        agent = load_sb3_policy(residual_run, env)
        assert isinstance(agent, ResidualAgent) and isinstance(agent.learned, SB3Policy)
        obs, _ = env.reset(seed=load_scenario("paper").validation_seeds[1])
        base = make_agent("incremental_ik", env).predict(obs)[0]
        learned = agent.learned.predict(obs)[0]
        np.testing.assert_array_equal(agent.predict(obs)[0], combine(base, learned, 0.05))
        spec = resolve_agent(str(residual_run))
        built = build_agent(spec, env, seed=0)
        np.testing.assert_array_equal(built.predict(obs)[0], agent.predict(obs)[0])
    finally:
        env.close()


@pytest.mark.parametrize(
    "value",
    [{"base": "oracle", "scale": 0.5}, {"base": "incremental_ik", "scale": 0}, "incremental_ik",
     {"base": "incremental_ik", "scale": 0.5, "extra": 1}, {"base": "dls", "scale": True}],
)  # fmt: skip
def test_a_bad_residual_declaration_is_one_clear_error(residual_run, tmp_path, value):
    import shutil

    from capture_bench.agents.policy_file import PolicyLoadError
    from capture_bench.agents.sb3_policy import read_metadata

    copy = tmp_path / "m"
    shutil.copytree(residual_run, copy)
    meta = json.loads((copy / "metadata.json").read_text())
    meta["residual"] = value
    (copy / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(PolicyLoadError, match="key 'residual'.*valid: null or"):
        read_metadata(copy)


def test_the_bases_are_the_public_deterministic_controllers():
    assert "incremental_ik" in RESIDUAL_BASES and "oracle" not in RESIDUAL_BASES
    assert "random" not in RESIDUAL_BASES
