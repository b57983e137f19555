"""Trained policies stored so that loading them runs no code: weights plus declared metadata.

An SB3 ``.zip`` carries pickled Python objects (the policy class, its keyword arguments, the
spaces, the learning-rate schedule), and unpickling a file can run any code its author put in it.
So a capture-bench model directory stores a policy as

* ``policy.pt``: the policy network's ``state_dict`` (tensors only), read with
  ``torch.load(..., weights_only=True)``, whose restricted unpickler builds tensors and plain
  containers and refuses everything else;
* ``metadata.json``: plain JSON declaring what the network is, validated field by field before
  anything is built::

      format: capture-bench-policy/1
      algorithm: PPO                    # PPO, A2C, SAC, TD3, DDPG (TQC with sb3-contrib)
      weights: policy.pt
      policy_kwargs: {net_arch: ..., activation_fn: tanh, log_std_init: -1.0, ...}
      observation_space: {type: Box, shape: [16], dtype: float32, low: [...], high: [...]}
                         # or, for the pixel observation, {type: Dict, spaces: {image: {type:
                         # Box, shape: [3, 84, 84], dtype: uint8, low: 0, high: 255}, state:
                         # a flat Box as above}}
      action_space: {type: Box, shape: [3], dtype: float32, low: [...], high: [...]}
      normalization: null | {mean: [...], var: [...], epsilon: 1e-8, clip_obs: 10.0}

Loading rebuilds the algorithm's SB3 policy class from the declared keyword arguments and spaces
and loads the weights into it strictly (every tensor named and shaped as the declared network
expects). The result acts exactly as the same model loaded by SB3 (tested on every algorithm).
`save_policy` writes this form from a trained SB3 model; ``train.py`` calls it, and
``python -m capture_bench.agents.convert DIR --trust-model`` (`capture_bench.agents.convert`)
converts an existing SB3 model directory (which unpickles it: only for files you trust).

The writer and the validating reader of one file format live together: the validation rules are
the format's definition and must be read beside what writes it.
"""

from __future__ import annotations

import importlib
import inspect
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "capture-bench-policy/1"
WEIGHTS_FILE = "policy.pt"
METADATA_FILE = "metadata.json"

# Model files (``policy.pt``, an SB3 ``.zip``, a checkpoint's ``parameters.pt``) are zip archives
# whose members torch and SB3 read whole into memory, each member's buffer allocated at the size
# the archive's central directory declares. So their sizes are checked before anything is read
# (`check_archive`): a few kilobytes of deflated zeros can declare gigabytes. The limits lie
# far above any model train.py writes (the largest shipped file is the pixel policy's .zip).
#: The most bytes a model file may hold on disk.
MAX_MODEL_FILE_BYTES = 512 * 2**20
#: The most bytes a model file's archive may declare, all its members uncompressed together.
MAX_UNCOMPRESSED_BYTES = 512 * 2**20
#: The highest ratio of the bytes an archive declares to its size on disk, where it declares more
#: than `RATIO_FLOOR_BYTES`: torch.save and SB3 store their members uncompressed (ratio 1;
#: deflated weights would give ~1.1), while deflated zeros, a zip bomb, reach ~1000.
MAX_COMPRESSION_RATIO = 100
#: Below this many declared bytes the ratio is not checked (a small archive exhausts nothing).
RATIO_FLOOR_BYTES = 16 * 2**20

#: Algorithm -> (module, class) of the SB3 policy that acts for it.
POLICY_CLASSES: dict[str, tuple[str, str]] = {
    "PPO": ("stable_baselines3.common.policies", "ActorCriticPolicy"),
    "A2C": ("stable_baselines3.common.policies", "ActorCriticPolicy"),
    "SAC": ("stable_baselines3.sac.policies", "SACPolicy"),
    "TD3": ("stable_baselines3.td3.policies", "TD3Policy"),
    "DDPG": ("stable_baselines3.td3.policies", "TD3Policy"),
    "TQC": ("sb3_contrib.tqc.policies", "TQCPolicy"),
}

#: Algorithm -> (module, class) of the SB3 policy that acts for it on a ``Dict`` observation.
MULTI_INPUT_POLICY_CLASSES: dict[str, tuple[str, str]] = {
    "PPO": ("stable_baselines3.common.policies", "MultiInputActorCriticPolicy"),
    "A2C": ("stable_baselines3.common.policies", "MultiInputActorCriticPolicy"),
    "SAC": ("stable_baselines3.sac.policies", "MultiInputPolicy"),
    "TD3": ("stable_baselines3.td3.policies", "MultiInputPolicy"),
    "DDPG": ("stable_baselines3.td3.policies", "MultiInputPolicy"),
    "TQC": ("sb3_contrib.tqc.policies", "MultiInputPolicy"),
}
#: An image Box's declaration: channel-first uint8 with one bound for every entry.
IMAGE_DTYPE = "uint8"

#: Declared activation name -> torch.nn class name.
ACTIVATIONS = {
    "tanh": "Tanh",
    "relu": "ReLU",
    "elu": "ELU",
    "leaky_relu": "LeakyReLU",
    "gelu": "GELU",
    "silu": "SiLU",
    "selu": "SELU",
    "sigmoid": "Sigmoid",
}

_BOOL_KWARGS = (
    "ortho_init",
    "use_sde",
    "full_std",
    "use_expln",
    "squash_output",
    "share_features_extractor",
    "normalize_images",
)
_FLOAT_KWARGS = ("log_std_init", "clip_mean")
_INT_KWARGS = ("n_critics", "n_quantiles")
#: Every policy keyword argument a metadata file may declare; anything else is refused.
#: ``features_extractor`` names a class of ``capture_bench.agents.features.FEATURE_EXTRACTORS``
#: (SB3's ``features_extractor_class``; omitted: SB3's default, the raw observation).
POLICY_KWARGS = (
    "net_arch",
    "activation_fn",
    "features_extractor",
    *_BOOL_KWARGS,
    *_FLOAT_KWARGS,
    *_INT_KWARGS,
)
#: Constructor arguments that must hold their SB3 default to be exported (not declarable).
_DEFAULT_ONLY = {
    "features_extractor_kwargs": None,
}


class PolicyLoadError(ValueError):
    """A trained model cannot be used; the message names the file, what is wrong and the fix."""


@dataclass(frozen=True)
class ObservationNormalizer:
    """Frozen observation statistics of SB3's ``VecNormalize``, as plain numbers.

    ``normalize_obs(obs) = clip((obs - mean) / sqrt(var + epsilon), ±clip_obs)`` as float32,
    the arithmetic of ``VecNormalize.normalize_obs`` (so the same numbers, tested).

    Attributes:
        mean, var: running mean and variance of each observation entry, shape (n,), float64.
        epsilon: added to the variance.
        clip_obs: bound of the normalised observation.
    """

    mean: np.ndarray
    var: np.ndarray
    epsilon: float
    clip_obs: float

    def normalize_obs(self, observation: np.ndarray) -> np.ndarray:
        """Normalise one observation (n,) or a batch (k, n)."""
        normalized = (observation - self.mean) / np.sqrt(self.var + self.epsilon)
        return np.clip(normalized, -self.clip_obs, self.clip_obs).astype(np.float32)

    @classmethod
    def from_vecnormalize(cls, vecnormalize: Any) -> ObservationNormalizer | None:
        """The statistics of a ``VecNormalize`` (None if it does not normalise observations)."""
        if not getattr(vecnormalize, "norm_obs", False):
            return None
        rms = vecnormalize.obs_rms
        return cls(
            np.array(rms.mean, dtype=np.float64),
            np.array(rms.var, dtype=np.float64),
            float(vecnormalize.epsilon),
            float(vecnormalize.clip_obs),
        )

    def to_json(self) -> dict[str, Any]:
        """Plain numbers for ``metadata.json``."""
        return {
            "mean": [float(x) for x in self.mean],
            "var": [float(x) for x in self.var],
            "epsilon": self.epsilon,
            "clip_obs": self.clip_obs,
        }


@dataclass(frozen=True)
class PolicyDeclaration:
    """The validated network declaration of a ``metadata.json`` (see module docstring).

    Attributes:
        algorithm: SB3 algorithm name, a key of `POLICY_CLASSES`.
        policy_kwargs: keyword arguments of the policy class, JSON values (activation by name).
        observation_space: a Box declaration (type, shape, dtype, low, high), or a Dict one
            (type, spaces: name -> Box declaration).
        action_space: a Box declaration.
        normalization: frozen observation statistics (of a Box observation), or None.
    """

    algorithm: str
    policy_kwargs: dict[str, Any]
    observation_space: dict[str, Any]
    action_space: dict[str, Any]
    normalization: ObservationNormalizer | None

    @property
    def multi_input(self) -> bool:
        """Whether the policy reads a ``Dict`` observation (the pixel observation)."""
        return self.observation_space["type"] == "Dict"


# --------------------------------------------------------------------------- validation


def _fail(where: str, key: str, value: Any, valid: str) -> PolicyLoadError:
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return PolicyLoadError(f"{where}: key {key!r} is {text}; valid: {valid}")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return (_is_int(value) or isinstance(value, float)) and math.isfinite(value)


def _layers(value: Any) -> bool:
    return isinstance(value, list) and all(_is_int(n) and 1 <= n <= 65536 for n in value)


def _check_net_arch(value: Any, where: str) -> None:
    if _layers(value):
        return
    if (
        isinstance(value, dict)
        and value
        and set(value) <= {"pi", "vf", "qf"}
        and all(_layers(v) for v in value.values())
    ):
        return
    raise _fail(
        where,
        "policy_kwargs.net_arch",
        value,
        "a list of layer sizes (1..65536) or a mapping of 'pi', 'vf', 'qf' to such lists",
    )


def _check_policy_kwargs(
    kwargs: Any, algorithm: str, where: str, multi_input: bool = False
) -> dict[str, Any]:
    if not isinstance(kwargs, dict):
        raise _fail(where, "policy_kwargs", kwargs, "a mapping of policy keyword arguments")
    for key, value in kwargs.items():
        name = f"policy_kwargs.{key}"
        if key not in POLICY_KWARGS:
            raise _fail(where, name, value, f"keys {', '.join(POLICY_KWARGS)}")
        if key == "net_arch":
            _check_net_arch(value, where)
        elif key == "activation_fn" and value not in ACTIVATIONS:
            raise _fail(where, name, value, ", ".join(ACTIVATIONS))
        elif key == "features_extractor" and value not in _feature_extractors():
            raise _fail(where, name, value, ", ".join(_feature_extractors()))
        elif key in _BOOL_KWARGS and not isinstance(value, bool):
            raise _fail(where, name, value, "true or false")
        elif key in _FLOAT_KWARGS and not _is_number(value):
            raise _fail(where, name, value, "a finite number")
        elif key in _INT_KWARGS and not (_is_int(value) and 1 <= value <= 1000):
            raise _fail(where, name, value, "an integer in 1..1000")
    policy_class = _policy_class(algorithm, where, multi_input)
    accepted = set(inspect.signature(policy_class.__init__).parameters)
    accepted.add("features_extractor")  # declared by name, built as features_extractor_class
    for key in kwargs:
        if key not in accepted:
            valid = ", ".join(k for k in POLICY_KWARGS if k in accepted)
            raise _fail(where, f"policy_kwargs.{key}", kwargs[key], f"for {algorithm}: {valid}")
    return dict(kwargs)


def _check_box(value: Any, key: str, where: str) -> dict[str, Any]:
    valid = "{type: Box, shape: [n], dtype: float32, low: [n numbers], high: [n numbers]}"
    if not isinstance(value, dict) or value.get("type") != "Box":
        raise _fail(where, key, value, valid)
    shape = value.get("shape")
    if not (isinstance(shape, list) and len(shape) == 1 and _is_int(shape[0]) and shape[0] >= 1):
        raise _fail(where, f"{key}.shape", shape, "[n] with n >= 1 (a flat Box)")
    if value.get("dtype") not in ("float32", "float64"):
        raise _fail(where, f"{key}.dtype", value.get("dtype"), "float32 or float64")
    for bound in ("low", "high"):
        numbers = value.get(bound)
        if not (
            isinstance(numbers, list)
            and len(numbers) == shape[0]
            and all(_is_int(x) or isinstance(x, float) for x in numbers)
            and not any(isinstance(x, float) and math.isnan(x) for x in numbers)
        ):
            raise _fail(where, f"{key}.{bound}", numbers, f"a list of {shape[0]} numbers")
    if any(lo > hi for lo, hi in zip(value["low"], value["high"])):
        raise _fail(where, f"{key}.low", value["low"], "each entry <= the same entry of high")
    return value


def _check_image_box(value: dict[str, Any], key: str, where: str) -> dict[str, Any]:
    shape = value.get("shape")
    if not (
        isinstance(shape, list) and len(shape) == 3 and all(_is_int(n) and n >= 1 for n in shape)
    ):
        raise _fail(where, f"{key}.shape", shape, "[channels, height, width] (an image Box)")
    if value.get("dtype") != IMAGE_DTYPE:
        raise _fail(where, f"{key}.dtype", value.get("dtype"), f"{IMAGE_DTYPE} (an image Box)")
    if value.get("low") != 0 or value.get("high") != 255:
        bounds = [value.get("low"), value.get("high")]
        raise _fail(where, f"{key}.low/high", bounds, "0 and 255 (an image Box)")
    return value


def _check_observation_space(value: Any, where: str) -> dict[str, Any]:
    """A flat Box, or a Dict of named Boxes each flat or an image (the pixel observation)."""
    key = "observation_space"
    if not (isinstance(value, dict) and value.get("type") == "Dict"):
        return _check_box(value, key, where)
    spaces = value.get("spaces")
    if not (isinstance(spaces, dict) and spaces and all(isinstance(k, str) for k in spaces)):
        raise _fail(where, f"{key}.spaces", spaces, "a mapping of names to Box declarations")
    for name, box in spaces.items():
        if isinstance(box, dict) and isinstance(box.get("shape"), list) and len(box["shape"]) == 3:
            _check_image_box(box, f"{key}.spaces.{name}", where)
        else:
            _check_box(box, f"{key}.spaces.{name}", where)
    return value


def _check_normalization(value: Any, size: int | None, where: str) -> ObservationNormalizer | None:
    if value is None:
        return None
    if size is None:
        raise _fail(where, "normalization", value, "null for a Dict observation")
    if not isinstance(value, dict) or set(value) != {"mean", "var", "epsilon", "clip_obs"}:
        raise _fail(where, "normalization", value, "null or {mean, var, epsilon, clip_obs}")
    for key in ("mean", "var"):
        numbers = value[key]
        if not (isinstance(numbers, list) and len(numbers) == size):
            raise _fail(where, f"normalization.{key}", numbers, f"a list of {size} finite numbers")
        if not all(map(_is_number, numbers)):
            raise _fail(where, f"normalization.{key}", numbers, f"a list of {size} finite numbers")
    if any(v < 0 for v in value["var"]):
        raise _fail(where, "normalization.var", value["var"], "variances >= 0")
    for key in ("epsilon", "clip_obs"):
        if not (_is_number(value[key]) and value[key] > 0):
            raise _fail(where, f"normalization.{key}", value[key], "a finite number > 0")
    return ObservationNormalizer(
        np.array(value["mean"], dtype=np.float64),
        np.array(value["var"], dtype=np.float64),
        float(value["epsilon"]),
        float(value["clip_obs"]),
    )


def parse_declaration(data: dict[str, Any], where: str) -> PolicyDeclaration:
    """Validate the network declaration of a metadata mapping (see module docstring).

    Raises:
        PolicyLoadError: naming ``where``, the key, the bad value and what is valid.
    """
    if data.get("format") != FORMAT:
        raise _fail(where, "format", data.get("format"), FORMAT)
    algorithm = str(data.get("algorithm", "")).upper()
    if algorithm not in POLICY_CLASSES:
        raise _fail(where, "algorithm", data.get("algorithm"), ", ".join(POLICY_CLASSES))
    observation_space = _check_observation_space(data.get("observation_space"), where)
    action_space = _check_box(data.get("action_space"), "action_space", where)
    multi_input = observation_space["type"] == "Dict"
    size = None if multi_input else observation_space["shape"][0]
    return PolicyDeclaration(
        algorithm=algorithm,
        policy_kwargs=_check_policy_kwargs(
            data.get("policy_kwargs", {}), algorithm, where, multi_input
        ),
        observation_space=observation_space,
        action_space=action_space,
        normalization=_check_normalization(data.get("normalization"), size, where),
    )


# --------------------------------------------------------------------------- building


def _feature_extractors() -> dict[str, Any]:
    """Declared name -> features extractor class (imported only when a policy is built)."""
    from capture_bench.agents.features import FEATURE_EXTRACTORS

    return FEATURE_EXTRACTORS


def _policy_class(algorithm: str, where: str, multi_input: bool = False) -> Any:
    module_name, class_name = (MULTI_INPUT_POLICY_CLASSES if multi_input else POLICY_CLASSES)[
        algorithm
    ]
    try:
        return getattr(importlib.import_module(module_name), class_name)
    except ImportError:
        package = module_name.split(".")[0].replace("_", "-")
        raise PolicyLoadError(
            f"{where}: algorithm {algorithm} needs the package {package}; pip install {package}"
        ) from None


def _box(declared: dict[str, Any]) -> Any:
    from gymnasium import spaces

    if declared["type"] == "Dict":
        return spaces.Dict({name: _box(box) for name, box in declared["spaces"].items()})
    dtype = np.dtype(declared["dtype"])
    if len(declared["shape"]) > 1:  # an image: one bound for every entry
        shape = tuple(declared["shape"])
        return spaces.Box(declared["low"], declared["high"], shape=shape, dtype=dtype)
    low = np.array(declared["low"], dtype=dtype)
    high = np.array(declared["high"], dtype=dtype)
    return spaces.Box(low=low, high=high, dtype=dtype)


def _zero_schedule(_progress: float) -> float:
    return 0.0  # the optimiser SB3 builds with the policy is never stepped here


class _NoOptimizer:
    """What SB3 builds as a policy's optimiser (``optimizer_class``) when the policy only acts:
    nothing. A torch optimiser's construction imports ``torch._dynamo`` (seconds of a process
    that only evaluates), and a policy that only acts never steps one."""

    def __init__(self, params: Any, lr: float = 0.0, **kwargs: Any) -> None:
        del params, lr, kwargs


def build_policy(declaration: PolicyDeclaration, where: str) -> Any:
    """The declared SB3 policy, untrained (weights as initialised; the caller loads them).

    The construction's random initialisation does not touch the caller's torch random stream.
    """
    import torch
    from torch import nn

    kwargs = dict(declaration.policy_kwargs)
    if "activation_fn" in kwargs:
        kwargs["activation_fn"] = getattr(nn, ACTIVATIONS[kwargs["activation_fn"]])
    if "features_extractor" in kwargs:
        kwargs["features_extractor_class"] = _feature_extractors()[kwargs.pop("features_extractor")]
    kwargs["optimizer_class"] = _NoOptimizer
    policy_class = _policy_class(declaration.algorithm, where, declaration.multi_input)
    with torch.random.fork_rng(devices=[]):
        try:
            policy = policy_class(
                _box(declaration.observation_space),
                _box(declaration.action_space),
                _zero_schedule,
                **kwargs,
            )
        except Exception as exc:  # a declaration SB3 cannot build: say which, not SB3's trace
            raise PolicyLoadError(
                f"{where}: cannot build a {declaration.algorithm} policy from policy_kwargs "
                f"{declaration.policy_kwargs} ({str(exc).splitlines()[0] if str(exc) else exc!r})"
            ) from None
    policy.set_training_mode(False)
    return policy


def _mib(count: int) -> str:
    return f"{count / 2**20:.0f} MiB" if count >= 2**20 else f"{count} bytes"


def check_archive(
    path: Path,
    error: type[ValueError] = PolicyLoadError,
    *,
    capped: bool = True,
    require_zip: bool = True,
) -> None:
    """Refuse a model file whose size would exhaust memory when read, before reading it: more
    than `MAX_MODEL_FILE_BYTES` on disk, not a zip archive (torch.save writes one; its
    legacy format allocates what it declares before reading it), or a central directory
    declaring more than `MAX_UNCOMPRESSED_BYTES` in all or more than
    `MAX_COMPRESSION_RATIO` times the size on disk. ``capped`` False: only the ratio is
    checked (a checkpoint's replay buffer is as large as the run chose). ``require_zip`` False: a
    file that is no zip archive is left to its reader to refuse (SB3's loader names an SB3
    ``.zip`` that is not one).

    Raises:
        ``error``: one line naming the file, its size and the limit.
    """
    import zipfile

    try:
        size = path.stat().st_size
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if capped and size > MAX_MODEL_FILE_BYTES:
        raise error(
            f"{path}: {_mib(size)} on disk, more than the {_mib(MAX_MODEL_FILE_BYTES)} a model "
            "file may hold; refused before loading it"
        )
    try:
        with zipfile.ZipFile(path) as archive:
            declared = sum(info.file_size for info in archive.infolist())
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        if not require_zip:
            return
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise error(
            f"{path}: not a zip archive ({reason}), the form torch.save and numpy.savez write; "
            "refused before any reader, torch.load(weights_only=True) included, sees it"
        ) from None
    if capped and declared > MAX_UNCOMPRESSED_BYTES:
        raise error(
            f"{path}: its zip archive declares {_mib(declared)} uncompressed, more than the "
            f"{_mib(MAX_UNCOMPRESSED_BYTES)} a model file may hold; refused before loading it"
        )
    if declared > RATIO_FLOOR_BYTES and declared > MAX_COMPRESSION_RATIO * max(size, 1):
        raise error(
            f"{path}: its zip archive declares {_mib(declared)} uncompressed from {_mib(size)} "
            f"on disk, a compression ratio above the {MAX_COMPRESSION_RATIO} a model file may "
            "have (a zip bomb); refused before loading it"
        )


def read_weights(path: Path) -> dict[str, Any]:
    """The tensors of a ``policy.pt``, read with ``weights_only=True`` (nothing else unpickled),
    after `check_archive` has checked its sizes.

    Raises:
        PolicyLoadError: missing file, too large a file or archive, a file torch's weights-only
            reader refuses (for example one that would build a Python object or call a
            function), or not a mapping of parameter names to tensors.
    """
    import torch

    if not path.is_file():
        raise PolicyLoadError(f"{path}: weights file is missing")
    check_archive(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises UnpicklingError, RuntimeError, EOFError, ...
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PolicyLoadError(
            f"{path}: not a weights-only policy file (refused by torch.load(weights_only=True): "
            f"{reason})"
        ) from None
    if not isinstance(state, dict) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
    ):
        raise PolicyLoadError(f"{path}: expected a mapping of parameter names to tensors")
    return state


def load_weights(policy: Any, state: dict[str, Any], where: str, algorithm: str) -> None:
    """Load ``state`` into ``policy``: every declared tensor present, with its shape, none extra."""
    expected = policy.state_dict()
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    if missing or unexpected:
        detail = "; ".join(
            f"{label}: {', '.join(names[:3])}{' ...' if len(names) > 3 else ''}"
            for label, names in (("missing", missing), ("unexpected", unexpected))
            if names
        )
        raise PolicyLoadError(
            f"{where}: the weights are not those of the declared {algorithm} policy ({detail}); "
            "does the metadata name the algorithm and policy_kwargs the model was trained with?"
        )
    for name, tensor in state.items():
        if tuple(tensor.shape) != tuple(expected[name].shape):
            raise PolicyLoadError(
                f"{where}: tensor {name!r} has shape {tuple(tensor.shape)}, the declared "
                f"{algorithm} policy expects {tuple(expected[name].shape)}; check policy_kwargs"
            )
    policy.load_state_dict(state, strict=True)


# --------------------------------------------------------------------------- saving


def _activation_name(activation: Any) -> str:
    for name, class_name in ACTIVATIONS.items():
        if getattr(activation, "__name__", None) == class_name:
            return name
    raise PolicyLoadError(
        f"activation {activation!r} cannot be declared; valid: {', '.join(ACTIVATIONS)}"
    )


def _space_json(space: Any) -> dict[str, Any]:
    from gymnasium import spaces

    if isinstance(space, spaces.Dict):
        return {"type": "Dict", "spaces": {k: _space_json(v) for k, v in space.spaces.items()}}
    image = (
        isinstance(space, spaces.Box)
        and len(space.shape) == 3
        and space.dtype == np.dtype(IMAGE_DTYPE)
        and bool((space.low == 0).all() and (space.high == 255).all())
    )
    if image:
        shape = [int(n) for n in space.shape]
        return {"type": "Box", "shape": shape, "dtype": IMAGE_DTYPE, "low": 0, "high": 255}
    if not isinstance(space, spaces.Box) or len(space.shape) != 1:
        raise PolicyLoadError(
            f"only flat Box spaces, uint8 images (0-255) and Dicts of them can be declared, "
            f"not {space}"
        )
    return {
        "type": "Box",
        "shape": [int(space.shape[0])],
        "dtype": str(space.dtype),
        "low": [float(x) for x in space.low],
        "high": [float(x) for x in space.high],
    }


def declare(algorithm: str, policy: Any, normalizer: ObservationNormalizer | None) -> dict:
    """The metadata entries that declare ``policy`` (an SB3 policy of ``algorithm``)."""
    algorithm = algorithm.upper()
    if algorithm not in POLICY_CLASSES:
        raise PolicyLoadError(f"algorithm {algorithm!r}; valid: {', '.join(POLICY_CLASSES)}")
    params = policy._get_constructor_parameters()
    if getattr(policy, "share_features_extractor", True) is False:  # SB3 leaves it out
        params["share_features_extractor"] = False
    kwargs: dict[str, Any] = {}
    names = {cls: name for name, cls in _feature_extractors().items()}
    extractor = params.get("features_extractor_class")
    if extractor not in names:
        valid = ", ".join(cls.__name__ for cls in names)
        raise PolicyLoadError(
            f"policy features_extractor_class={extractor!r} cannot be declared (only {valid})"
        )
    if names[extractor] != "flatten":
        kwargs["features_extractor"] = names[extractor]
    for key, default in _DEFAULT_ONLY.items():
        value = params.get(key)
        if (getattr(value, "__name__", value) or None) != default:
            raise PolicyLoadError(f"policy {key}={value!r} cannot be declared (only {default})")
    for key in POLICY_KWARGS:
        if key not in params or key == "features_extractor":
            continue
        value = params[key]
        if key == "activation_fn":
            value = _activation_name(value)
        elif key in _BOOL_KWARGS:
            value = bool(value)
        elif key in _FLOAT_KWARGS:
            value = float(value)
        elif key in _INT_KWARGS:
            value = int(value)
        elif key == "net_arch" and value is not None:
            value = json.loads(json.dumps(value))  # tuples -> lists, copies
        if value is not None:
            kwargs[key] = value
    return {
        "format": FORMAT,
        "algorithm": algorithm,
        "weights": WEIGHTS_FILE,
        "policy_kwargs": kwargs,
        "observation_space": _space_json(policy.observation_space),
        "action_space": _space_json(policy.action_space),
        "normalization": None if normalizer is None else normalizer.to_json(),
    }


def policy_files(
    algorithm: str,
    policy: Any,
    normalizer: ObservationNormalizer | None = None,
    extra: dict[str, Any] | None = None,
    where: str = "policy",
) -> tuple[bytes, bytes]:
    """The contents of ``policy.pt`` and ``metadata.json`` (``extra`` entries first) declaring
    ``policy``, checked to read back as a declaration; nothing is written.

    Raises:
        PolicyLoadError: naming ``where``: a policy the format cannot declare.
    """
    import io

    import torch

    try:
        declaration = declare(algorithm, policy, normalizer)
    except PolicyLoadError as exc:
        raise PolicyLoadError(f"{where}: {exc}") from None
    metadata = {**(extra or {}), **declaration}
    parse_declaration(metadata, where)  # what we write, we can read
    text = json.dumps(metadata, indent=2, allow_nan=False) + "\n"
    # no copies: tensors shared by two modules (a features extractor that the actor and the
    # critic share) keep one storage, written once
    state = {k: v.detach().cpu() for k, v in policy.state_dict().items()}
    buffer = io.BytesIO()
    torch.save(state, buffer)
    return buffer.getvalue(), text.encode()


def write_policy_files(directory: Path, weights: bytes, metadata: bytes) -> Path:
    """Write `policy_files`' contents into ``directory`` (created if missing).

    Each file is written to a temporary name and renamed, so an interrupted write leaves the
    previous files whole. The weights are written before the metadata that names them.

    Returns:
        The metadata file.
    """
    from capture_bench.files import atomic_write

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    atomic_write(directory / WEIGHTS_FILE, weights)
    atomic_write(directory / METADATA_FILE, metadata)
    return directory / METADATA_FILE


def save_policy(
    directory: Path,
    algorithm: str,
    policy: Any,
    normalizer: ObservationNormalizer | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``policy.pt`` and ``metadata.json`` (``extra`` entries first) into ``directory``:
    `policy_files`, then `write_policy_files` (atomic, weights first).

    Args:
        directory: the model directory (created if missing).
        algorithm: SB3 algorithm name.
        policy: the SB3 policy (``model.policy``).
        normalizer: frozen observation statistics, if training normalised observations.
        extra: provenance entries (scenario, hyper-parameters, command, ...), plain JSON.

    Returns:
        The metadata file.
    """
    directory = Path(directory)
    weights, metadata = policy_files(
        algorithm, policy, normalizer, extra, str(directory / METADATA_FILE)
    )
    return write_policy_files(directory, weights, metadata)
