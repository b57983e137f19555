"""Training draws episodes only from a scenario's training seeds, never an evaluation or a
validation seed (``load_scenario`` refuses a scenario whose ranges overlap)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from capture_bench.task.scenarios import ConfigError, Scenario


def check_training_seed(seed: int, scenario: Scenario) -> None:
    """Raise :class:`ConfigError` unless ``seed`` is a training seed (never an evaluation or a
    validation seed)."""
    train, evaluation = scenario.training_seeds, scenario.evaluation_seeds
    validation = scenario.validation_seeds
    if seed in validation:
        raise ConfigError(
            f"seed {seed} is one of scenario {scenario.name!r}'s validation seeds "
            f"({validation.start}-{validation.stop - 1}); training may use seeds "
            f"{train.start}-{train.stop - 1}"
        )
    if seed in set(evaluation):
        raise ConfigError(
            f"seed {seed} is one of scenario {scenario.name!r}'s evaluation seeds "
            f"({evaluation[0]}-{evaluation[-1]}); training may use seeds "
            f"{train.start}-{train.stop - 1}"
        )
    if seed not in train:
        raise ConfigError(
            f"seed {seed} is outside scenario {scenario.name!r}'s training seeds "
            f"({train.start}-{train.stop - 1})"
        )


class TrainingSeeds(gym.Wrapper):
    """Give every episode an explicit seed drawn from the scenario's training seeds.

    The seed passed to :meth:`reset` (SB3 passes one on the first reset) only re-seeds the draw;
    episodes themselves never use a seed outside ``scenario.training_seeds`` and never an
    evaluation seed, so training cannot see an evaluation episode.

    Args:
        env: a capture-bench environment.
        scenario: its scenario (for the seed ranges).
        seed: seeds the draw until :meth:`reset` is given another.
    """

    def __init__(self, env: gym.Env, scenario: Scenario, seed: int) -> None:
        super().__init__(env)
        self._range = scenario.training_seeds
        self._excluded = set(scenario.evaluation_seeds) | set(scenario.validation_seeds)
        self._rng = np.random.default_rng(seed)
        self.episode_seed: int | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        while True:
            episode_seed = int(self._rng.integers(self._range.start, self._range.stop))
            if episode_seed not in self._excluded:
                break
        self.episode_seed = episode_seed
        return self.env.reset(seed=episode_seed, options=options)
