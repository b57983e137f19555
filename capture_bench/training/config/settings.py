"""A run's validated hyper-parameters as one frozen, typed object: `TrainingSettings`.

`TrainingSettings.from_mapping` validates a hyper-parameter mapping exactly as
[`validate_hyperparameters`][capture_bench.training.config.hyperparameters.validate_hyperparameters]
does (the same messages, the same defaults); `TrainingSettings.to_mapping` gives that validated
mapping back, its keys in the same order, which is what ``hyperparameters.yaml``,
``config.json`` and ``metadata.json`` hold. The keys ``train.py`` reads itself are fields; the
SB3 algorithm's own keys stay together in `TrainingSettings.algorithm`. A change (an option that
wins over the file, a curriculum's steps) makes a new object with `dataclasses.replace`.
No SB3 or torch import happens at module level.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from capture_bench.task.scenarios import Scenario
from capture_bench.training.config.hyperparameters import (
    ALGO_KEYS,
    TRAINING_KEYS,
    memory_estimate,
    pixel_env_options,
    planned_steps,
    resolve_hyperparameters,
    sb3_kwargs,
    steps_per_update,
    validate_hyperparameters,
)

#: SB3's discount where a file leaves ``gamma`` out (the same for every algorithm).
SB3_GAMMA = 0.99


@dataclass(frozen=True)
class TrainingSettings:
    """A run's validated hyper-parameters: ``configs/algos/<algo>.yaml``'s keys (those of
    [`TRAINING_KEYS`][capture_bench.training.config.hyperparameters.TRAINING_KEYS], in its
    order) as fields, and the algorithm's own in `algorithm`. A field that is None is a key the
    validated mapping leaves out (no curriculum, no imitation, no residual scale without a
    residual, no ``image_size`` or ``mixture_weights``).

    Build it with `from_mapping` (validation) or `from_validated` (a mapping already
    validated); the mappings it holds are its own copies, to be read, not changed.
    """

    algo: str  # ppo, a2c, sac, td3, ddpg or tqc
    n_envs: int
    total_timesteps: int
    policy: str = "MlpPolicy"
    policy_kwargs: Mapping[str, Any] = field(default_factory=dict)
    normalize: bool = False
    reward: str = "dense"
    checkpoint_freq: int = 0
    eval_freq: int = 0
    eval_episodes: int = 5
    residual: str = "none"
    residual_scale: float | None = None  # 0.5 where a residual leaves it out
    curriculum_tolerance: float | None = None
    imitate: str | Mapping[str, str] | None = None  # a controller, or one per scenario
    imitation_rounds: int | None = None  # the imitation's keys: set with imitate, else None
    imitation_steps: int | None = None
    imitation_epochs: int | None = None
    imitation_warmup: int | None = None
    imitation_floor: float | None = None
    imitation_lr: float | None = None
    imitation_batch: int | None = None
    imitation_state_weight: float | None = None
    imitation_keypoint_weight: float | None = None
    mixture_weights: Mapping[str, Any] | None = None
    curriculum_hold: float | None = None
    curriculum_steps: int | None = None  # `with_curriculum_steps` fills it in for a run
    curriculum_delay: int | None = None  # 0 where a curriculum leaves it out
    image_size: int | None = None
    frame_stack: int | None = None  # the pixel observation's options: None, the env's default
    ee_crop: int | None = None
    ee_crop_scale: int | None = None
    image_supersample: int | None = None
    ee_crop_supersample: int | None = None
    augment_shift: int | None = None  # DrQ's random shift of training batches, pixels only
    asymmetric_critic: bool | None = None  # the critic reads the true state, pixels only
    front_end: str | None = None  # the pose a front end reads from the image, pixels only
    front_end_stack: int | None = None  # its steps the policy reads: set with front_end
    #: SB3's own keys for the algorithm (``learning_rate``, ``n_steps``, ...), as validated.
    algorithm: Mapping[str, Any] = field(default_factory=dict)
    #: The validated mapping's keys in its order (`to_mapping` writes them so).
    order: tuple[str, ...] = field(default=(), repr=False, compare=False)

    @classmethod
    def from_mapping(
        cls, data: Any, algo: str, source: str, features_from: str | None = None
    ) -> TrainingSettings:
        """Validate a complete hyper-parameter mapping for ``algo``:
        [`validate_hyperparameters`][capture_bench.training.config.hyperparameters.validate_hyperparameters]
        (``source`` and ``features_from`` name the files in its messages).

        Raises:
            ConfigError: not a mapping, an unknown key, or a bad value.
        """
        return cls.from_validated(validate_hyperparameters(data, algo, source, features_from), algo)

    @classmethod
    def from_validated(cls, data: Mapping[str, Any], algo: str) -> TrainingSettings:
        """The settings of a mapping `validate_hyperparameters` returned for ``algo`` (nothing
        is checked again; its mappings are copied).

        Raises:
            ValueError: ``data`` holds a key neither a training key nor ``algo``'s.
        """
        unknown = [key for key in data if key not in TRAINING_KEYS and key not in ALGO_KEYS[algo]]
        if unknown:
            raise ValueError(f"not a validated hyper-parameter of {algo}: {unknown[0]!r}")
        copied = copy.deepcopy(dict(data))
        own = {key: value for key, value in copied.items() if key in TRAINING_KEYS}
        algorithm = {key: value for key, value in copied.items() if key not in TRAINING_KEYS}
        return cls(algo=algo, **own, algorithm=algorithm, order=tuple(copied))

    def to_mapping(self) -> dict[str, Any]:
        """The validated mapping: the keys in `order` that are set, then any set since (by
        `dataclasses.replace`) in field order; a copy the caller may change."""
        present: dict[str, Any] = {}
        for key in TRAINING_KEYS:
            value = getattr(self, key)
            if value is not None:
                present[key] = value
        present.update(self.algorithm)
        keys = [key for key in self.order if key in present]
        keys += [key for key in present if key not in self.order]
        return {key: copy.deepcopy(present[key]) for key in keys}

    @property
    def gamma(self) -> float:
        """The discount: ``gamma`` where the file gives it, else SB3's default."""
        return self.algorithm.get("gamma", SB3_GAMMA)

    @property
    def pixel_size(self) -> tuple[int, int] | None:
        """The pixel observation's (width, height) where ``image_size`` is set, else None
        ([`image_size`][capture_bench.training.config.hyperparameters.image_size])."""
        return None if self.image_size is None else (self.image_size, self.image_size)

    @property
    def front_end_spec(self) -> Any:
        """The front end the policy reads the pixels through
        (`capture_bench.agents.sb3_policy.FrontEnd`: its name, stack and image size, the
        default image where ``image_size`` is left out), or None without one."""
        if self.front_end is None:
            return None
        from capture_bench.agents.sb3_policy import FrontEnd
        from capture_bench.sensing.workspace_image import IMAGE_SIZE

        stack = self.front_end_stack
        assert stack is not None  # set with front_end by validate_hyperparameters
        return FrontEnd(self.front_end, stack, self.pixel_size or IMAGE_SIZE)

    @property
    def pixel_options(self) -> dict[str, Any]:
        """The pixel observation's env keyword arguments these settings give: ``image_size``
        and the options they set
        ([`pixel_env_options`][capture_bench.training.config.hyperparameters.pixel_env_options])."""
        return pixel_env_options(self.to_mapping())

    @property
    def has_curriculum(self) -> bool:
        """A tolerance or hold curriculum is asked for."""
        return self.curriculum_tolerance is not None or self.curriculum_hold is not None

    def with_curriculum_steps(self) -> TrainingSettings:
        """These settings, where a curriculum leaves out ``curriculum_steps``, with half the
        run's ``total_timesteps`` (at least 1) as its steps."""
        if not self.has_curriculum or self.curriculum_steps is not None:
            return self
        return dataclasses.replace(self, curriculum_steps=max(1, self.total_timesteps // 2))

    def sb3_kwargs(self) -> dict[str, Any]:
        """The SB3 algorithm's constructor arguments
        ([`sb3_kwargs`][capture_bench.training.config.hyperparameters.sb3_kwargs])."""
        return sb3_kwargs(self.to_mapping(), self.algo)

    def steps_per_update(self) -> int:
        """Environment steps between two looks at the budget
        ([`steps_per_update`][capture_bench.training.config.hyperparameters.steps_per_update])."""
        return steps_per_update(self.algo, self.to_mapping())

    def planned_steps(self, done: int = 0) -> int:
        """The step count the run ends at from ``done`` steps
        ([`planned_steps`][capture_bench.training.config.hyperparameters.planned_steps])."""
        return planned_steps(self.algo, self.to_mapping(), done)

    def memory_estimate(self, pixels: bool, resume: bool = False) -> list[tuple[str, str, int]]:
        """The memory the run allocates beyond its envs, part by part
        ([`memory_estimate`][capture_bench.training.config.hyperparameters.memory_estimate])."""
        return memory_estimate(self.algo, self.to_mapping(), pixels, resume)


def resolve_settings(
    algo: str,
    scenario: Scenario | None,
    path: str | Path | None = None,
    overrides: Sequence[str] = (),
) -> tuple[TrainingSettings, Path, dict[str, Any]]:
    """[`resolve_hyperparameters`][capture_bench.training.config.hyperparameters.resolve_hyperparameters]
    with the validated mapping as `TrainingSettings` (the file and the layers' origin as
    there).

    Raises:
        ConfigError: an unknown algorithm, file, key or section, or a bad value.
    """
    data, file, origin = resolve_hyperparameters(algo, scenario, path, overrides)
    return TrainingSettings.from_validated(data, algo), file, origin
