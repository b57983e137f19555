"""Trained Stable-Baselines3 policies as :class:`agents.protocol.Agent`.

A trained model lives in a directory (a training run directory, or an entry ``models/<name>/``)
holding the SB3 ``.zip`` and a metadata file, ``metadata.json`` or ``metadata.yaml``::

    algorithm: PPO            # one of PPO, SAC, TD3, A2C, DDPG (required)
    scenario: paper           # the scenario it was trained on (informational)
    model: model.zip          # the SB3 file in the directory (optional if there is exactly one)
    vecnormalize: vecnormalize.pkl   # VecNormalize statistics, if training normalised observations
    observation_source: ekf   # what it was trained on (informational; evaluation uses the env's)

``train.py`` writes this format. Observations are normalised with the saved VecNormalize
statistics (frozen, as in SB3's evaluation) before the policy sees them.

Loading checks the model's observation and action spaces against the environment's and raises
:class:`PolicyLoadError` (a ``ValueError``) with a one-line message on any problem: no metadata,
unknown algorithm, missing or corrupt ``.zip``, mismatched spaces. SB3 and torch are imported only
when a model is loaded.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ALGORITHMS = ("PPO", "SAC", "TD3", "A2C", "DDPG")
METADATA_FILES = ("metadata.json", "metadata.yaml", "metadata.yml")


class PolicyLoadError(ValueError):
    """A trained model cannot be used; the message names the file and what is wrong."""


@dataclass(frozen=True)
class ModelMetadata:
    """What a model directory says about its model.

    Attributes:
        directory: the model directory.
        algorithm: SB3 algorithm name, one of :data:`ALGORITHMS`.
        model_file: the SB3 ``.zip``.
        scenario: scenario it was trained on ('' if not given).
        metadata_file: the metadata file read.
        vecnormalize_file: saved VecNormalize statistics, or None.
        observation_source: observation source used in training ('' if not given).
    """

    directory: Path
    algorithm: str
    model_file: Path
    scenario: str
    metadata_file: Path
    vecnormalize_file: Path | None = None
    observation_source: str = ""


def find_metadata_file(directory: Path) -> Path | None:
    """The metadata file of a model directory, or None."""
    for name in METADATA_FILES:
        if (directory / name).is_file():
            return directory / name
    return None


def read_metadata(directory: str | Path) -> ModelMetadata:
    """Read and validate a model directory's metadata (see module docstring)."""
    directory = Path(directory)
    if not directory.is_dir():
        raise PolicyLoadError(f"{directory}: no such model directory")
    meta_file = find_metadata_file(directory)
    if meta_file is None:
        raise PolicyLoadError(
            f"{directory}: no metadata file; expected one of {', '.join(METADATA_FILES)} "
            f"naming the algorithm ({', '.join(ALGORITHMS)})"
        )
    try:
        text = meta_file.read_text()
        data = json.loads(text) if meta_file.suffix == ".json" else yaml.safe_load(text)
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise PolicyLoadError(f"{meta_file}: unreadable metadata ({exc})") from None
    if not isinstance(data, dict):
        raise PolicyLoadError(f"{meta_file}: expected a mapping with key 'algorithm'")
    algorithm = str(data.get("algorithm", data.get("algo", ""))).upper()
    if algorithm not in ALGORITHMS:
        raise PolicyLoadError(
            f"{meta_file}: key 'algorithm' is {data.get('algorithm')!r}; "
            f"valid: {', '.join(ALGORITHMS)}"
        )
    if "model" in data:
        model_file = directory / str(data["model"])
    else:
        zips = sorted(directory.glob("*.zip"))
        if len(zips) != 1:
            found = ", ".join(p.name for p in zips) or "none"
            raise PolicyLoadError(
                f"{directory}: expected exactly one SB3 .zip (found: {found}); "
                f"or name it with key 'model' in {meta_file.name}"
            )
        model_file = zips[0]
    if not model_file.is_file():
        raise PolicyLoadError(f"{model_file}: model file is missing")
    vecnormalize = data.get("vecnormalize")
    vecnormalize_file = directory / str(vecnormalize) if vecnormalize else None
    if vecnormalize_file is not None and not vecnormalize_file.is_file():
        raise PolicyLoadError(f"{vecnormalize_file}: VecNormalize statistics file is missing")
    return ModelMetadata(
        directory=directory,
        algorithm=algorithm,
        model_file=model_file,
        scenario=str(data.get("scenario", "")),
        metadata_file=meta_file,
        vecnormalize_file=vecnormalize_file,
        observation_source=str(data.get("observation_source") or ""),
    )


def load_model(metadata: ModelMetadata) -> Any:
    """Load the SB3 model on the CPU; a corrupt file raises :class:`PolicyLoadError`."""
    import stable_baselines3

    algorithm_class = getattr(stable_baselines3, metadata.algorithm)
    try:
        return algorithm_class.load(str(metadata.model_file), device="cpu")
    except Exception as exc:  # SB3 raises many kinds on a bad file; all mean "cannot load"
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise PolicyLoadError(
            f"{metadata.model_file}: not a loadable {metadata.algorithm} model ({reason})"
        ) from None


def load_normalizer(metadata: ModelMetadata) -> Any:
    """The frozen VecNormalize statistics of the model (None if it has none).

    Only ``normalize_obs`` is used, which needs no vectorised environment attached.
    """
    if metadata.vecnormalize_file is None:
        return None
    import pickle

    try:
        with open(metadata.vecnormalize_file, "rb") as handle:
            normalizer = pickle.load(handle)
        normalizer.training = False
        normalizer.norm_reward = False
        normalizer.normalize_obs(np.zeros(normalizer.observation_space.shape, np.float32))
    except Exception as exc:  # a bad pickle can raise almost anything
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise PolicyLoadError(
            f"{metadata.vecnormalize_file}: not loadable VecNormalize statistics ({reason})"
        ) from None
    return normalizer


def _describe(space: Any) -> str:
    shape = getattr(space, "shape", None)
    return f"{type(space).__name__}{tuple(shape) if shape is not None else ''}"


def _same_box(a: Any, b: Any) -> bool:
    if type(a).__name__ != type(b).__name__ or getattr(a, "shape", None) != getattr(b, "shape", 0):
        return False
    if hasattr(a, "low") and hasattr(b, "low"):
        return bool(np.allclose(a.low, b.low) and np.allclose(a.high, b.high))
    return a == b


def check_spaces(model: Any, observation_space: Any, action_space: Any, where: str) -> None:
    """Raise :class:`PolicyLoadError` unless the model's spaces equal the environment's.

    Args:
        model: a loaded SB3 model.
        observation_space, action_space: the environment's spaces.
        where: names the model and the environment in the message.
    """
    for kind, ours, theirs in (
        ("observation", model.observation_space, observation_space),
        ("action", model.action_space, action_space),
    ):
        if not _same_box(ours, theirs):
            raise PolicyLoadError(
                f"{where}: model {kind} space {_describe(ours)} does not match the "
                f"environment's {_describe(theirs)}"
            )


class SB3Policy:
    """A loaded SB3 model behind the :class:`agents.protocol.Agent` protocol.

    Args:
        model: the SB3 model (its ``predict`` does the work).
        name: label for reports.
        normalizer: frozen VecNormalize statistics applied to observations first, or None.
    """

    privileged = False

    def __init__(self, model: Any, name: str = "sb3", normalizer: Any = None) -> None:
        from stable_baselines3.common.distributions import DiagGaussianDistribution
        from stable_baselines3.common.policies import ActorCriticPolicy

        self.model = model
        self.name = name
        self.normalizer = normalizer
        # Whether the deterministic action is the action net's output (the Gaussian's mean).
        policy = model.policy
        self._mean_is_action = isinstance(policy, ActorCriticPolicy) and (
            type(policy.action_dist) is DiagGaussianDistribution
        )

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3's ``predict``: observation (16,) -> ``(action (3,), state)``."""
        if self.normalizer is not None:
            observation = self.normalizer.normalize_obs(observation)
        obs = np.asarray(observation)
        if deterministic and state is None and obs.shape == self.model.observation_space.shape:
            return self._deterministic_action(obs), None
        action, state = self.model.predict(
            observation, state=state, episode_start=episode_start, deterministic=deterministic
        )
        return np.asarray(action, dtype=np.float32), state

    def _deterministic_action(self, obs: np.ndarray) -> np.ndarray:
        """``model.predict(obs, deterministic=True)`` for one Box observation, without its
        per-call checks and, for actor-critic policies, without building the action distribution
        only to take its mode: the mean of a diagonal Gaussian is the action net's output.
        The same torch operations on the same numbers, so the same action (tested).
        """
        import torch
        from stable_baselines3.common.policies import BasePolicy

        policy = self.model.policy
        with torch.no_grad():
            tensor = torch.as_tensor(obs, dtype=torch.float32).unsqueeze(0)
            if self._mean_is_action:
                # the actor's features, shared extractor or not (BasePolicy's method)
                features = BasePolicy.extract_features(policy, tensor, policy.pi_features_extractor)
                actions = policy.action_net(policy.mlp_extractor.forward_actor(features))
            else:
                actions = policy._predict(tensor, deterministic=True)
        action = actions.numpy().reshape(self.model.action_space.shape)
        if policy.squash_output:  # as BasePolicy.predict does for a Box action space
            action = policy.unscale_action(action)
        else:
            action = np.clip(action, self.model.action_space.low, self.model.action_space.high)
        return np.asarray(action, dtype=np.float32)

    def reset(self) -> None:
        """Nothing to forget: recurrent state, if any, is passed through ``predict``."""


def load_sb3_policy(directory: str | Path, env: Any, name: str | None = None) -> SB3Policy:
    """Load the model in ``directory`` and check it fits ``env``.

    Raises:
        PolicyLoadError: bad metadata, missing or corrupt model, or mismatched spaces.
    """
    metadata = read_metadata(directory)
    model = load_model(metadata)
    label = name or metadata.directory.name
    check_spaces(model, env.observation_space, env.action_space, f"{metadata.model_file}")
    return SB3Policy(model, label, load_normalizer(metadata))
