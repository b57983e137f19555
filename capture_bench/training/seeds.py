"""Training draws episodes only from a scenario's training seeds, never an evaluation or a
validation seed (``load_scenario`` refuses a scenario whose ranges overlap)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from capture_bench.task.scenarios import ConfigError, Scenario


def check_training_seed(seed: int, scenario: Scenario) -> None:
    """Raise [`ConfigError`][capture_bench.ConfigError] unless ``seed`` is a training seed (never an
    evaluation or a
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


class TrainingSeedDraw:
    """A stream of episode seeds drawn uniformly from ``scenario.training_seeds``, skipping any
    evaluation or validation seed; one per sub-env, shared by `TrainingSeeds` and
    `capture_bench.training.common.sb3_vec_env.CaptureSB3VecEnv` so that both draw the same
    episodes.

    Args:
        scenario: the scenario (for the seed ranges).
        seed: seeds the draw's generator (``numpy.random.default_rng``).
    """

    def __init__(self, scenario: Scenario, seed: int) -> None:
        self._range = scenario.training_seeds
        self._excluded = set(scenario.evaluation_seeds) | set(scenario.validation_seeds)
        self._rng = np.random.default_rng(seed)

    def reseed(self, seed: int) -> None:
        """Restart the draw from ``seed``."""
        self._rng = np.random.default_rng(seed)

    def next(self) -> int:
        """The next episode seed, a training seed."""
        while True:
            episode_seed = int(self._rng.integers(self._range.start, self._range.stop))
            if episode_seed not in self._excluded:
                return episode_seed


class TrainingSeeds(gym.Wrapper):
    """Give every episode an explicit seed drawn from the scenario's training seeds.

    The seed passed to `reset` (SB3 passes one on the first reset) only re-seeds the draw;
    episodes themselves never use a seed outside ``scenario.training_seeds`` and never an
    evaluation seed, so training cannot see an evaluation episode.

    Args:
        env: a capture-bench environment.
        scenario: its scenario (for the seed ranges); None: the env's own
            (``env.unwrapped.scenario``), so that the wrapper can be built from the env alone, as
            the RL Zoo's ``env_wrapper`` does (``configs/zoo/``).
        seed: seeds the draw until `reset` is given another.
    """

    def __init__(self, env: gym.Env, scenario: Scenario | None = None, seed: int = 0) -> None:
        super().__init__(env)
        if scenario is None:
            scenario = env.unwrapped.scenario  # type: ignore[attr-defined]
        self._draw = TrainingSeedDraw(scenario, seed)
        self.episode_seed: int | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        if seed is not None:
            self._draw.reseed(seed)
        self.episode_seed = self._draw.next()
        return self.env.reset(seed=self.episode_seed, options=options)
