"""train.py: a 64-step PPO run that loads back as an agent, resume, and one-line user errors."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from stand_in import TINY_PPO

import train
from capture_bench.task.scenarios import ConfigError, list_scenarios, load_scenario
from capture_bench.training.config.hyperparameters import (
    load_hyperparameters,
    validate_hyperparameters,
)
from capture_bench.training.seeds import TrainingSeeds, check_training_seed

TINY = TINY_PPO


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 64-step PPO run on paper (module scope: one training for the tests that read it)."""
    root = tmp_path_factory.mktemp("train")
    config = root / "tiny.yaml"
    config.write_text(TINY)
    run_dir = root / "run"
    argv = ["--algo", "ppo", "--scenario", "paper", "--config", str(config)]
    assert train.main([*argv, "--run-dir", str(run_dir), "--seed", "3"]) == 0
    return run_dir, config


def test_run_writes_model_metadata_checkpoints_and_tensorboard(trained):
    run_dir, _ = trained
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["algorithm"] == "PPO" and meta["scenario"] == "paper"
    assert meta["env_id"] == "CaptureBench/Paper-v1" and meta["model"] == "model.zip"
    assert meta["observation_source"] == "ekf" and meta["seed"] == 3
    assert meta["total_timesteps"] == 64
    assert meta["hyperparameters"]["policy_kwargs"]["net_arch"] == [16]
    assert "stable-baselines3" in meta["packages"]
    assert sorted(p.name for p in (run_dir / "checkpoints").iterdir()) == [
        "step_32",
        "step_64",
    ]
    assert list((run_dir / "tb").rglob("events.out.tfevents.*"))
    assert not list(run_dir.rglob(".tmp-*"))  # every save was renamed into place


def test_trained_model_loads_as_an_agent_acting_in_the_action_space(trained):
    from capture_bench.agents.sb3_policy import load_sb3_policy
    from capture_bench.envs.capture_env import CaptureEnv

    env = CaptureEnv("paper")
    try:
        agent = load_sb3_policy(trained[0], env)
        obs, _ = env.reset(seed=load_scenario("paper").evaluation_seeds[0])
        for _ in range(3):
            action, _ = agent.predict(obs, deterministic=True)
            assert action.shape == (3,) and env.action_space.contains(action)
            obs, *_ = env.step(action)
    finally:
        env.close()


def test_resume_continues_the_step_count(trained, tmp_path):
    import shutil

    run_dir = tmp_path / "run"
    shutil.copytree(trained[0], run_dir)
    assert train.main(["--resume", str(run_dir), "--total-timesteps", "128"]) == 0
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["total_timesteps"] == 128 and meta["seed"] == 3
    assert (run_dir / "checkpoints" / "step_128" / "parameters.pt").is_file()


def test_a_moved_run_resumes_in_its_new_directory(tmp_path):
    """config.json records where a run started; a run moved since (or resumed on another node by a
    sweep) writes its validations, best/ and final policy where it is now."""
    import csv

    config = tmp_path / "tiny.yaml"
    config.write_text(TINY + "eval_freq: 32\neval_episodes: 1\n")
    first = tmp_path / "first"
    assert train.main(["--algo", "ppo", "--config", str(config), "--run-dir", str(first)]) == 0
    moved = tmp_path / "moved"
    first.rename(moved)
    assert train.main(["--resume", str(moved), "--total-timesteps", "128"]) == 0
    assert not first.exists()
    with open(moved / "validations.csv") as handle:
        assert [int(row["step"]) for row in csv.DictReader(handle)] == [32, 64, 96, 128]
    assert json.loads((moved / "metadata.json").read_text())["total_timesteps"] == 128


def test_sac_resume_restores_replay_buffer_and_vecnormalize(tmp_path):
    from capture_bench.training.common.checkpoint import read_checkpoint

    config = tmp_path / "sac.yaml"
    config.write_text(
        "n_envs: 1\ntotal_timesteps: 48\nlearning_starts: 16\n"
        "policy_kwargs: {net_arch: [16], features_extractor: flatten}\n"  # normalize needs it
        "batch_size: 16\nbuffer_size: 1000\ncheckpoint_freq: 48\nnormalize: true\n"
    )
    run_dir = tmp_path / "run"
    assert train.main(["--algo", "sac", "--config", str(config), "--run-dir", str(run_dir)]) == 0
    assert train.main(["--resume", str(run_dir), "--total-timesteps", "64"]) == 0
    checkpoint = read_checkpoint(run_dir / "checkpoints" / "step_64")
    assert checkpoint.state["replay_buffer"]["pos"] == 64  # the first 48 transitions were kept
    assert (checkpoint.buffer["rewards"][:64] != 0).all()
    assert checkpoint.state["vecnormalize"]["obs_rms"]["count"] > 64
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["algorithm"] == "SAC" and meta["vecnormalize"] == "vecnormalize.pkl"


def one_line_error(capsys, argv: list[str], *expected: str) -> None:
    assert train.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    for text in expected:
        assert text in err, err


def test_an_evaluation_seed_is_refused(capsys, tmp_path):
    seed = load_scenario("paper").evaluation_seeds[0]
    one_line_error(capsys, ["--seed", str(seed), "--run-dir", str(tmp_path / "r")], "evaluation")
    assert not (tmp_path / "r").exists()


def test_bad_algo_unknown_key_and_bad_value_are_one_line_exit_2(capsys, tmp_path):
    one_line_error(capsys, ["--algo", "dqn"], "dqn", "ppo, a2c, sac, td3, ddpg, tqc")
    unknown = tmp_path / "unknown.yaml"
    unknown.write_text(TINY + "learning_rat: 0.001\n")
    one_line_error(
        capsys, ["--config", str(unknown)], str(unknown), "learning_rat", "learning_rate"
    )
    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY + "gamma: 1.5\n")
    one_line_error(capsys, ["--config", str(bad)], str(bad), "gamma", "1.5", "[0, 1]")
    one_line_error(capsys, ["--vec-env", "ray"], "batched", "dummy", "subproc")


def test_shipped_algo_files_are_valid():
    from capture_bench.training.config.hyperparameters import ALGO_DIR, ALGORITHMS

    assert sorted(p.stem for p in ALGO_DIR.glob("*.yaml")) == sorted(ALGORITHMS)
    for algo in ALGORITHMS:
        hp, _ = load_hyperparameters(algo)
        assert hp["n_envs"] >= 1 and hp["total_timesteps"] >= 1


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ({"n_envs": 1, "total_timesteps": 8, "learning_rate": "lin_3e-4"}, "lin_3e-4"),
        (
            {"n_envs": 1, "total_timesteps": 8, "learning_rate": "3e-4"},
            3e-4,
        ),  # YAML's 3e-4 is a str
    ],
)
def test_learning_rate_forms(data, expected):
    assert validate_hyperparameters(data, "ppo", "x.yaml")["learning_rate"] == expected


def test_bad_values_name_what_is_valid():
    base = {"n_envs": 1, "total_timesteps": 8}
    with pytest.raises(ConfigError, match="'n_steps'.*whole number"):
        validate_hyperparameters({**base, "n_steps": 2.5}, "ppo", "x.yaml")
    with pytest.raises(ConfigError, match="policy_kwargs.net_arch"):
        validate_hyperparameters({**base, "policy_kwargs": {"net_arch": [0]}}, "ppo", "x.yaml")
    with pytest.raises(ConfigError, match="missing key 'total_timesteps'"):
        validate_hyperparameters({"n_envs": 1}, "ppo", "x.yaml")


class _SeedRecorder(gym.Env):
    """Records the seed of every reset."""

    observation_space = gym.spaces.Box(-1, 1, (1,))
    action_space = gym.spaces.Box(-1, 1, (1,))

    def __init__(self):
        self.seeds = []

    def reset(self, *, seed=None, options=None):
        self.seeds.append(seed)
        return np.zeros(1, np.float32), {}


def test_training_episodes_use_training_seeds_only():
    # training seeds 999990-1000009 overlap the evaluation seeds 1000000-1000099 on purpose;
    # load_scenario refuses that, so the scenario is built past it: the wrapper still excludes them
    paper = load_scenario("paper")
    seeds = dataclasses.replace(paper.seeds, training_start=999_990, training_count=20)
    scenario = dataclasses.replace(paper, seeds=seeds)
    inner = _SeedRecorder()
    wrapper = TrainingSeeds(inner, scenario, seed=0)
    for i in range(100):
        wrapper.reset(seed=1_000_000 if i == 0 else None)  # a given seed only re-seeds the draw
    assert set(inner.seeds) == set(range(999_990, 1_000_000))


@pytest.mark.parametrize("algorithm", ["shipped PPO", "PPO", "PPO unshared", "SAC", "TD3", "A2C"])
def test_deterministic_predict_shortcut_equals_sb3_predict(algorithm):
    """SB3Policy's shortcut for deterministic actions gives exactly model.predict's action."""
    import stable_baselines3

    from capture_bench.agents.sb3_policy import SB3Policy
    from capture_bench.envs.capture_env import CaptureEnv

    env = CaptureEnv("paper")
    try:
        if algorithm == "shipped PPO":  # the original SB3 file (ours, so trusted)
            zip_file = Path(__file__).parents[1] / "models" / "dagger-dls-paper" / "model.zip"
            model = stable_baselines3.PPO.load(zip_file, device="cpu")
        else:
            name, _, variant = algorithm.partition(" ")
            policy_kwargs: dict = {"net_arch": [32, 32]}
            if variant == "unshared":  # separate actor and critic feature extractors
                policy_kwargs["share_features_extractor"] = False
            kwargs = {"policy_kwargs": policy_kwargs, "seed": 0, "device": "cpu"}
            model = getattr(stable_baselines3, name)("MlpPolicy", env, **kwargs)
        agent = SB3Policy(model.policy, algorithm)
        rng = np.random.default_rng(0)
        for scale in (0.1, 1.0, 10.0):  # 10: actions far outside [-1, 1] before clipping
            for _ in range(20):
                obs = rng.uniform(-scale, scale, 16).astype(np.float32)
                expected, _ = model.predict(obs, deterministic=True)
                action, state = agent.predict(obs, deterministic=True)
                assert state is None and action.dtype == np.float32
                np.testing.assert_array_equal(action, expected)
    finally:
        env.close()


def test_the_three_seed_ranges_are_disjoint_and_an_overlap_is_refused(tmp_path):
    for name in list_scenarios():
        s = load_scenario(name)
        train_seeds, evaluation, validation = (
            set(s.training_seeds),
            set(s.evaluation_seeds),
            set(s.validation_seeds),
        )
        assert len(validation) == 1000 and min(validation) == max(evaluation) + 1, name
        assert not (train_seeds & evaluation or train_seeds & validation), name
    bad = tmp_path / "overlap.yaml"
    bad.write_text("seeds:\n  evaluation_start: 999950\n")  # training is 0-999999
    with pytest.raises(ConfigError, match=r"key 'seeds': the training seeds 0-999999 overlap"):
        load_scenario(bad)
    with pytest.raises(ConfigError, match="validation seeds"):
        check_training_seed(load_scenario("paper").validation_seeds[0], load_scenario("paper"))


def test_training_time_evaluation_uses_validation_seeds_only(tmp_path, monkeypatch):
    """A tiny run with the periodic evaluation on: every episode any env of the run resets to is
    a training seed or, for the evaluation, one of the first validation seeds; none is published.
    Resets of single envs and of batched envs (training's default and the validation's) count."""
    from capture_bench.envs.capture_env import CaptureEnv
    from capture_bench.envs.vector_env import CaptureVectorEnv

    seen: list[int | None] = []
    reset, vector_reset = CaptureEnv.reset, CaptureVectorEnv.reset

    def recording_reset(self, *, seed=None, options=None):
        seen.append(seed)
        return reset(self, seed=seed, options=options)

    def recording_vector_reset(self, *, seed=None, options=None):
        # one explicit seed per sub-env (the validation) or none (training: each sub-env's
        # seed source, CaptureVectorEnv.set_episode_seeds); an int would seed s, s + 1, ...
        assert seed is None or isinstance(seed, list)
        out = vector_reset(self, seed=seed, options=options)
        mask = (options or {}).get("reset_mask", [True] * self.num_envs)
        played = self.episode_seeds  # the seed of the episode each sub-env now plays
        assert all(s is not None for s, here in zip(played, mask) if here)
        seen.extend(s for s, here in zip(played, mask) if here)
        return out

    monkeypatch.setattr(CaptureEnv, "reset", recording_reset)
    monkeypatch.setattr(CaptureVectorEnv, "reset", recording_vector_reset)
    config = tmp_path / "tiny.yaml"
    config.write_text(TINY + "eval_freq: 32\neval_episodes: 2\n")
    argv = ["--algo", "ppo", "--scenario", "paper", "--config", str(config)]
    assert train.main([*argv, "--run-dir", str(tmp_path / "run")]) == 0
    paper = load_scenario("paper")
    validation = [s for s in seen if s in paper.validation_seeds]
    assert set(validation) == set(paper.validation_seeds[:2]) and len(validation) == 4  # 2 evals
    assert all(s in paper.training_seeds for s in seen if s not in paper.validation_seeds)
    assert not set(seen) & set(paper.evaluation_seeds)


def test_a_batched_training_run_never_imports_filterpy(tmp_path):
    """filterpy is the tests' reference filter only: a training process never imports it (nor
    scipy.stats, which its import pulls in)."""
    import subprocess
    import sys

    config = tmp_path / "tiny.yaml"
    config.write_text(TINY.replace("n_envs: 1", "n_envs: 2"))
    script = (
        "import sys, train\n"
        f"argv = ['--config', {str(config)!r}, '--run-dir', {str(tmp_path / 'run')!r}]\n"
        "assert train.main(argv) == 0\n"
        "print(sorted(m for m in ('filterpy', 'scipy.stats') if m in sys.modules))\n"
    )
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run(
        [sys.executable, "-c", script], cwd=root, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout + out.stderr
