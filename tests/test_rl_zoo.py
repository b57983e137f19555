"""The RL Zoo's hyper-parameter files (``configs/zoo/<algo>.yml``): what the generator makes from
``configs/algos/`` today, one entry per registered env ID, read by the Zoo into exactly the SB3
arguments, curricula and wrapper ``train.py`` builds, and a short Zoo training run with the file.

The tests that run the Zoo skip where ``rl_zoo3`` is not installed (the ``zoo`` extra)."""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import yaml

import capture_bench
from capture_bench.task.scenarios import ConfigError, list_scenarios, load_scenario
from capture_bench.training.common.build import curriculum_callbacks, fill_curriculum_steps
from capture_bench.training.config.hyperparameters import ALGORITHMS
from capture_bench.training.config.options import TrainConfig
from capture_bench.training.config.settings import TrainingSettings, resolve_settings
from capture_bench.training.zoo.command import ZOO_DIR, main, zoo_entry, zoo_file, zoo_path

ROOT = Path(__file__).resolve().parents[1]
SCENARIO_OF = {load_scenario(name).env_id: name for name in list_scenarios()}
SCHEDULES = ("learning_rate", "clip_range")


def _resolved(algo: str, name: str) -> TrainingSettings:
    settings, _, _ = resolve_settings(algo, load_scenario(name))
    return fill_curriculum_steps(settings)


def _at(schedule, progress: float) -> float:
    return schedule(progress) if callable(schedule) else schedule


def test_the_committed_files_are_what_the_generator_makes_from_configs_algos():
    assert sorted(p.name for p in ZOO_DIR.iterdir()) == sorted(f"{a}.yml" for a in ALGORITHMS)
    for algo in ALGORITHMS:
        assert zoo_path(ZOO_DIR, algo).read_text(encoding="utf-8") == zoo_file(algo), (
            f"configs/zoo/{algo}.yml is stale: python -m capture_bench zoo-hyperparams"
        )


def test_every_entry_names_a_registered_capture_bench_env_id():
    for algo in ALGORITHMS:
        entries = yaml.safe_load(zoo_path(ZOO_DIR, algo).read_text(encoding="utf-8"))
        assert list(entries) == capture_bench.env_ids(), algo  # every scenario, nothing else
        assert all(env_id in gym.registry for env_id in entries)
        assert all(isinstance(entry, dict) and entry["n_timesteps"] for entry in entries.values())


def test_the_command_writes_the_files_and_check_names_a_stale_one(tmp_path, capsys):
    assert main(["--algo", "ppo", "sac", "--out", str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ppo.yml", "sac.yml"]
    assert (tmp_path / "ppo.yml").read_text() == zoo_path(ZOO_DIR, "ppo").read_text()
    (tmp_path / "sac.yml").write_text("# edited by hand\n")
    capsys.readouterr()
    assert main(["--algo", "ppo", "sac", "--out", str(tmp_path), "--check"]) == 1
    err = capsys.readouterr().err
    assert "sac.yml" in err and "ppo.yml" not in err and len(err.splitlines()) == 1
    assert main(["--algo", "dqn", "--out", str(tmp_path / "new")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "dqn" in err and "ppo" in err
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"residual": "incremental_ik", "residual_scale": 0.5}, "residual"),
        ({"policy": "MultiInputPolicy", "image_size": 84}, "pixel observations"),
    ],
)
def test_a_setting_no_zoo_entry_can_carry_is_refused_by_name(change, named):
    settings = dataclasses.replace(_resolved("ppo", "paper"), **change)
    with pytest.raises(ConfigError, match=named):
        zoo_entry(settings, load_scenario("paper"), "my_ppo.yaml")


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_the_zoo_reads_each_entry_into_what_train_py_builds(algo, tmp_path):
    """The Zoo's own reading of the file (its ExperimentManager: schedules, policy_kwargs,
    action noise, callbacks) gives, for every env ID, the SB3 arguments ``sb3_kwargs`` makes from
    ``configs/algos/<algo>.yaml`` and the curricula ``train.py`` adds."""
    pytest.importorskip("rl_zoo3")
    from rl_zoo3.exp_manager import ExperimentManager

    from capture_bench.training.callbacks import RolloutMetrics

    path = zoo_path(ZOO_DIR, algo)
    actions = SimpleNamespace(action_space=gym.spaces.Box(-1, 1, (3,), np.float32))
    for env_id in yaml.safe_load(path.read_text(encoding="utf-8")):
        name = SCENARIO_OF[env_id]
        manager = ExperimentManager(
            argparse.Namespace(), algo, env_id, str(tmp_path), config=str(path), verbose=0
        )
        raw, saved = manager.read_hyperparameters()
        kwargs, env_wrapper, callbacks, _ = manager._preprocess_hyperparams(raw)
        kwargs = manager._preprocess_action_noise(kwargs, saved, actions)
        settings = _resolved(algo, name)
        hp, ours = settings.to_mapping(), settings.sb3_kwargs()
        where = f"{algo} {env_id}"
        assert manager.n_envs == hp["n_envs"] and manager.n_timesteps == hp["total_timesteps"]
        assert manager.normalize == hp["normalize"], where
        assert manager.env_kwargs == {"reward": hp["reward"]}, where
        assert kwargs.pop("policy") == hp["policy"]
        assert set(kwargs) == set(ours), where
        for key, value in ours.items():
            if key in SCHEDULES:
                progress = (1.0, 0.5, 0.0)
                assert [_at(kwargs[key], p) for p in progress] == [_at(value, p) for p in progress]
            elif key == "action_noise":
                assert repr(kwargs[key]) == repr(value), where
            else:
                assert kwargs[key] == value, f"{where}: {key}"
        train_py = curriculum_callbacks(TrainConfig(algo=algo, scenario=name), settings)
        assert [type(c) for c in callbacks] == [RolloutMetrics, *map(type, train_py)], where
        for zoo, built in zip(callbacks[1:], train_py):
            assert (zoo.start, zoo.steps, zoo.delay) == (built.start, built.steps, built.delay)
            assert np.array_equal(zoo.final, built.final), where
        assert env_wrapper is not None
    env = env_wrapper(gym.make(env_id))  # the last entry's: episodes on training seeds only
    try:
        env.reset(seed=load_scenario(name).evaluation_seeds[0])  # only re-seeds the draw
        assert env.get_wrapper_attr("episode_seed") in load_scenario(name).training_seeds
    finally:
        env.close()


class _ZooConfigLoader(yaml.SafeLoader):
    """Reads the Zoo's ``config.yml``: an OrderedDict dumped by ``yaml.dump``."""


_ZooConfigLoader.add_constructor(
    "tag:yaml.org,2002:python/object/apply:collections.OrderedDict",
    lambda loader, node: dict(loader.construct_sequence(node, deep=True)[0]),
)


def test_the_zoo_trains_a_few_thousand_steps_with_the_shipped_file(tmp_path):
    """``python -m rl_zoo3.train`` with configs/zoo/ppo.yml on paper (16 envs instead of 64, to
    keep the test short: one rollout fills one 1024-sample batch, as in the file): it exits 0,
    evaluates, saves a model with our settings and records our entry as its config; the model
    converts to the safe form."""
    pytest.importorskip("rl_zoo3")
    from stable_baselines3 import PPO
    from torch import nn

    from capture_bench.agents.features import RelativeLogDistance

    env_id, conf = "CaptureBench/Paper-v1", zoo_path(ZOO_DIR, "ppo")
    command = [
        sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", env_id,
        "--gym-packages", "capture_bench", "--conf-file", str(conf), "-n", "2048",
        "--hyperparams", "n_envs:16", "--seed", "3", "--num-threads", "1",
        "--eval-freq", "1024", "--eval-episodes", "1", "--log-folder", str(tmp_path / "logs"),
    ]  # fmt: skip
    pythonpath = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    done = subprocess.run(
        command, cwd=tmp_path, env={**os.environ, "PYTHONPATH": pythonpath},
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "rollout/" in done.stdout and "capture_rate" in done.stdout  # RolloutMetrics ran
    run = tmp_path / "logs" / "ppo" / "CaptureBench-Paper-v1_1"
    assert (run / "evaluations.npz").is_file()
    assert "is_success" in (run / "0.monitor.csv").read_text().splitlines()[1]
    saved = yaml.load((run / "CaptureBench-Paper-v1" / "config.yml").read_text(), _ZooConfigLoader)
    ours = yaml.safe_load(conf.read_text(encoding="utf-8"))[env_id]
    assert saved == {**ours, "n_envs": 16}
    hp = _resolved("ppo", "paper").to_mapping()
    model = PPO.load(run / "CaptureBench-Paper-v1.zip", device="cpu")  # the file it just wrote
    assert (model.n_steps, model.batch_size, model.n_epochs) == (64, 1024, 5)
    assert (model.n_steps, model.batch_size) == (hp["n_steps"], hp["batch_size"])
    assert model.lr_schedule(1.0) == hp["learning_rate"] and model.gamma == hp["gamma"]
    assert model.num_timesteps == 2048
    assert model.policy.net_arch == hp["policy_kwargs"]["net_arch"]
    assert isinstance(model.policy.features_extractor, RelativeLogDistance)
    assert model.policy.activation_fn is nn.Tanh
    # the Zoo's model converts to the safe form, which evaluate.py loads without unpickling
    from capture_bench.agents.convert import main as convert
    from capture_bench.agents.sb3_policy import load_sb3_policy

    model_dir = tmp_path / "zoo-model"
    model_dir.mkdir()
    shutil.copy(run / "CaptureBench-Paper-v1.zip", model_dir)
    (model_dir / "metadata.json").write_text('{"algorithm": "PPO"}')
    assert convert([str(model_dir), "--trust-model"]) == 0
    (model_dir / "CaptureBench-Paper-v1.zip").unlink()  # the safe form alone from here on
    env = gym.make(env_id)
    try:
        policy = load_sb3_policy(model_dir, env)
        obs, _ = env.reset(seed=load_scenario("paper").evaluation_seeds[0])
        action, _ = policy.predict(obs, deterministic=True)
        assert np.array_equal(action, model.predict(obs, deterministic=True)[0])
    finally:
        env.close()
