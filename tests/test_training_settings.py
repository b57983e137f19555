"""`TrainingSettings`: the validated hyper-parameters as a frozen object, read from and written
back to exactly the mapping `validate_hyperparameters` makes (keys in the same order), refusing
what it refuses with its messages, changed only by making a new object."""

from __future__ import annotations

import dataclasses
import pickle

import pytest
import yaml

from capture_bench.task.scenarios import ConfigError, list_scenarios, load_scenario
from capture_bench.training.common.build import fill_curriculum_steps
from capture_bench.training.config.hyperparameters import (
    ALGO_DIR,
    ALGO_KEYS,
    ALGORITHMS,
    TRAINING_KEYS,
    planned_steps,
    resolve_hyperparameters,
    sb3_kwargs,
    steps_per_update,
    validate_hyperparameters,
)
from capture_bench.training.config.settings import TrainingSettings, resolve_settings


def _top_level(algo: str) -> dict:
    """The shipped file's own keys (its scenario sections left out)."""
    data = yaml.safe_load((ALGO_DIR / f"{algo}.yaml").read_text())
    return {k: v for k, v in data.items() if k in TRAINING_KEYS or k in ALGO_KEYS[algo]}


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_every_shipped_file_goes_through_the_settings_unchanged_in_its_key_order(algo):
    top = _top_level(algo)
    expected = validate_hyperparameters(top, algo, "x.yaml")
    back = TrainingSettings.from_mapping(top, algo, "x.yaml").to_mapping()
    assert back == expected and list(back) == list(expected)
    reordered = dict(reversed(list(top.items())))  # the input's order is what is kept
    expected = validate_hyperparameters(reordered, algo, "x.yaml")
    back = TrainingSettings.from_mapping(reordered, algo, "x.yaml").to_mapping()
    assert list(back) == list(expected) and back == expected
    for name in list_scenarios():  # every scenario section, layered as train.py reads it
        hp, _, origin = resolve_hyperparameters(algo, load_scenario(name))
        settings, _, again = resolve_settings(algo, load_scenario(name))
        assert again == origin
        assert settings.to_mapping() == hp and list(settings.to_mapping()) == list(hp), name
        assert TrainingSettings.from_mapping(hp, algo, name).to_mapping() == hp


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_the_helpers_compute_what_the_mapping_functions_do(algo):
    hp, _, _ = resolve_hyperparameters(algo, load_scenario("paper"))
    settings = TrainingSettings.from_validated(hp, algo)
    assert settings.steps_per_update() == steps_per_update(algo, hp)
    assert settings.planned_steps(7) == planned_steps(algo, hp, 7)
    assert settings.gamma == hp.get("gamma", 0.99)
    ours, theirs = settings.sb3_kwargs(), sb3_kwargs(hp, algo)
    assert set(ours) == set(theirs) and ours["policy_kwargs"] == theirs["policy_kwargs"]
    assert settings.pixel_size is None
    assert dataclasses.replace(settings, image_size=64).pixel_size == (64, 64)


def test_a_curriculums_steps_are_a_new_object_with_the_key_where_setdefault_put_it():
    hp, _, _ = resolve_hyperparameters("ppo", None, None, ["curriculum_tolerance=0.2"])
    settings = TrainingSettings.from_validated(hp, "ppo")
    filled = fill_curriculum_steps(settings)
    assert settings.curriculum_steps is None and "curriculum_steps" not in settings.to_mapping()
    expected = dict(hp)
    expected.setdefault("curriculum_steps", max(1, hp["total_timesteps"] // 2))
    assert filled.to_mapping() == expected and list(filled.to_mapping()) == list(expected)
    assert fill_curriculum_steps(filled) is filled  # given: kept
    plain = TrainingSettings.from_validated(resolve_hyperparameters("ppo", None)[0], "ppo")
    assert fill_curriculum_steps(plain) is plain  # no curriculum: nothing to fill


def test_an_option_that_wins_over_the_file_keeps_the_keys_place():
    hp = validate_hyperparameters(
        {"total_timesteps": 100, "gamma": 0.9, "n_envs": 2}, "ppo", "x.yaml"
    )
    settings = dataclasses.replace(
        TrainingSettings.from_validated(hp, "ppo"), n_envs=4, total_timesteps=512
    )
    assert list(settings.to_mapping()) == list(hp)
    assert settings.to_mapping() == {**hp, "n_envs": 4, "total_timesteps": 512}


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ({"n_envs": 1, "total_timesteps": 10, "gama": 0.9}, "unknown key 'gama'"),
        ({"n_envs": 0, "total_timesteps": 10}, "key 'n_envs'"),
        ({"n_envs": 1}, "missing key 'total_timesteps'"),
        ({"n_envs": 1, "total_timesteps": 10, "imitation_rounds": 2}, "needs imitate"),
        ([1, 2], "expected a mapping of hyper-parameters"),
    ],
)
def test_a_bad_key_or_value_is_refused_with_the_validations_message(data, expected):
    with pytest.raises(ConfigError) as validated:
        validate_hyperparameters(data, "ppo", "x.yaml")
    with pytest.raises(ConfigError, match=expected) as typed:
        TrainingSettings.from_mapping(data, "ppo", "x.yaml")
    assert str(typed.value) == str(validated.value)
    assert str(typed.value).startswith("x.yaml: ")


def test_the_settings_are_frozen_and_their_mapping_is_a_copy():
    hp, _, _ = resolve_hyperparameters("ppo", load_scenario("paper"))
    settings = TrainingSettings.from_validated(hp, "ppo")
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.n_envs = 3  # type: ignore[misc]
    out = settings.to_mapping()
    out["policy_kwargs"]["net_arch"] = [1]
    hp["policy_kwargs"]["net_arch"] = [2]  # the mapping it was made from is copied too
    assert settings.policy_kwargs["net_arch"] not in ([1], [2])
    assert pickle.loads(pickle.dumps(settings)) == settings  # subprocess envs get a copy
    with pytest.raises(ValueError, match="not a validated hyper-parameter of sac: "):
        TrainingSettings.from_validated(hp, "sac")  # PPO's keys


def test_the_fields_are_the_training_keys_in_their_order():
    names = [f.name for f in dataclasses.fields(TrainingSettings)]
    assert names == ["algo", *TRAINING_KEYS, "algorithm", "order"]
