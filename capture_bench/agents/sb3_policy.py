"""Trained Stable-Baselines3 policies as agents (`capture_bench.agents.protocol`), loaded
safely.

A trained model lives in a directory (a training run directory, or an entry ``models/<name>/``)
holding a metadata file, ``metadata.json`` (or ``metadata.yaml``), and the policy in one of two
forms:

* **safe** (what ``train.py`` writes and every shipped model uses): ``policy.pt`` (tensors only)
  and a metadata file declaring the network, its spaces and its normalisation statistics as plain
  numbers (`capture_bench.agents.policy_file`). Loading it unpickles nothing, so it runs no
  code.
* **SB3 ``.zip``** (``model.save``), with optional ``vecnormalize.pkl``: pickled Python objects,
  which can run any code when loaded. Loaded only with ``trust_model=True`` (``evaluate.py
  --trust-model``) and only where the directory has no safe form; without it, loading is refused
  with a message saying how to opt in or convert
  (``python -m capture_bench.agents.convert DIR --trust-model``).

The metadata of an SB3 ``.zip`` directory::

    algorithm: PPO            # one of PPO, A2C, SAC, TD3, DDPG (TQC with sb3-contrib)
    scenario: paper           # the scenario it was trained on (informational)
    model: model.zip          # the SB3 file in the directory (optional if there is exactly one)
    vecnormalize: vecnormalize.pkl   # VecNormalize statistics, if training normalised observations
    observation_source: ekf   # what it was trained on (informational; evaluation uses the env's)
    pixel_observation:        # with pixels: the options it was trained with (optional; checked)
      frame_stack: 3          # PixelOptions' keys (frame stack, end-effector crop, area sampling)

Observations are normalised with the frozen statistics (as SB3's evaluation does) before the
policy sees them. Every problem raises `PolicyLoadError` (a ``ValueError``) with a one-line
message: no metadata, unknown algorithm, missing or corrupt file, a declaration that does not
match the weights, an algorithm that does not match the ``.zip``, mismatched spaces. SB3 and torch
are imported only when a model is loaded.

The safe and the trusted loading paths and the fast deterministic action of each
algorithm family, each tested against SB3's own ``predict``.
"""

from __future__ import annotations

import json
import re
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from capture_bench.agents.policy_file import (
    MULTI_INPUT_POLICY_CLASSES,
    POLICY_CLASSES,
    ObservationNormalizer,
    PolicyDeclaration,
    PolicyLoadError,
    build_policy,
    check_archive,
    load_weights,
    parse_declaration,
    read_weights,
)
from capture_bench.sensing.sources import PIXELS
from capture_bench.sensing.workspace_image import IMAGE_SIZE, PIXEL_OPTION_RANGES, PixelOptions

ALGORITHMS = tuple(POLICY_CLASSES)
METADATA_FILES = ("metadata.json", "metadata.yaml", "metadata.yml")
#: The most bytes a metadata file may hold (checked before it is read): a declaration is a few
#: kilobytes of network settings, spaces and provenance.
MAX_METADATA_BYTES = 16 * 2**20
TRUST_HINT = (
    "an SB3 .zip holds pickled Python objects, which can run code when loaded: pass "
    "--trust-model (Python: trust_model=True) only if you trust its source, or convert it once "
    "with: python -m capture_bench.agents.convert {directory} --trust-model"
)


def observation_options(
    image_size: tuple[int, int] | None, pixel_options: Mapping[str, int] | None = None
) -> dict[str, Any]:
    """The env keyword arguments for a policy that sees images of ``image_size`` (pixels) with
    the pixel observation's ``pixel_options`` (`PixelOptions`'s, those set), or none for a
    policy that sees the estimate (``image_size`` None)."""
    if image_size is None:
        return {}
    return {"observation_source": PIXELS, "image_size": image_size, **(pixel_options or {})}


def _pixel_options(value: Any, meta_file: Path) -> dict[str, int]:
    """The metadata's ``pixel_observation`` entry, checked: None (the original observation) or
    a mapping of `PixelOptions`'s keys; the options that differ from their defaults."""
    if value is None:
        return {}
    valid = f"null or a mapping of {', '.join(PIXEL_OPTION_RANGES)} to whole numbers"
    if not isinstance(value, dict):
        raise PolicyLoadError(f"{meta_file}: key 'pixel_observation' is {value!r}; valid: {valid}")
    try:
        return PixelOptions.check(**value).changed()
    except ValueError as exc:
        raise PolicyLoadError(f"{meta_file}: key 'pixel_observation': {exc}") from None


@dataclass(frozen=True)
class FrontEnd:
    """A policy's front end (`capture_bench.agents.marker_pose`): its ``name``, the ``stack`` of
    steps the network reads, and the ``image_size`` (width, height) of the pixels it reads."""

    name: str
    stack: int
    image_size: tuple[int, int]

    def check(self, env: Any, where: str) -> None:
        """Raise `PolicyLoadError` unless ``env`` gives the pixel observation the front end reads:
        a ``Dict`` whose ``image`` is one frame of `image_size`."""
        space = env.observation_space
        image = getattr(space, "spaces", {}).get("image") if hasattr(space, "spaces") else None
        width, height = self.image_size
        if image is None or tuple(image.shape) != (3, height, width):
            raise PolicyLoadError(
                f"{where}: the model reads the camera's pixels through its front end {self.name} "
                f"(one {width} x {height} frame), the environment gives {_describe(space)}; "
                f"make the environment with observation_source='pixels', image_size=({width}, "
                f"{height}), frame_stack 1 and its card's other pixel_observation options"
            )

    def calibration(self, scenario: Any) -> Any:
        """What the front end knows of ``scenario``'s camera and target (a name or `Scenario`),
        for images of `image_size` (`capture_bench.agents.marker_pose.MarkerCalibration`)."""
        from capture_bench.agents.marker_pose import MarkerCalibration

        return MarkerCalibration.of_scenario(scenario, self.image_size)

    def agent(self, learned: Any, env: Any, name: str) -> Any:
        """The agent of ``learned`` (the network's) behind the front end, calibrated for
        ``env``'s scenario (`capture_bench.agents.marker_pose.MarkerPoseAgent`)."""
        from capture_bench.agents.marker_pose import MarkerPoseAgent

        calibration = self.calibration(env.unwrapped.task.scenario)
        return MarkerPoseAgent(learned, calibration, self.stack, name)

    def metadata(self) -> dict[str, Any]:
        """The metadata's ``front_end`` entry (`read_metadata` reads it back)."""
        return {"name": self.name, "stack": self.stack, "image_size": list(self.image_size)}


@dataclass(frozen=True)
class ModelMetadata:
    """What a model directory says about its model.

    Attributes:
        directory: the model directory.
        algorithm: SB3 algorithm name, one of `ALGORITHMS`.
        metadata_file: the metadata file read.
        scenario: scenario it was trained on ('' if not given).
        observation_source: observation source used in training ('' if not given).
        weights_file: the safe form's ``policy.pt``, or None (an SB3 ``.zip`` only).
        declaration: the safe form's validated network declaration, or None.
        model_file: the SB3 ``.zip``, or None (the safe form only).
        vecnormalize_file: the ``.zip``'s VecNormalize statistics, or None.
        residual: ``(base, scale)`` where the policy is a residual on an analytic controller
            (key ``residual: {base: incremental_ik, scale: 0.5}``;
            `capture_bench.agents.residual`), or None.
        actions: ``deterministic`` (the leaderboard's rule, the default) or ``sampled`` (key
            ``actions``: the model card declares that the policy acts with sampled actions,
            seeded per episode by evaluation).
        pixel_options: the pixel observation's options it was trained with (key
            ``pixel_observation``: frame stack, end-effector crop, area sampling;
            `PixelOptions`), those that differ from the defaults; empty: the original one.
        front_end: where the policy network reads a front end's vector of the pixel
            observation (key ``front_end: {name: marker_pose, stack: 3, image_size: [84, 84]}``;
            `capture_bench.agents.marker_pose`), or None.
    """

    directory: Path
    algorithm: str
    metadata_file: Path
    scenario: str = ""
    observation_source: str = ""
    weights_file: Path | None = None
    declaration: PolicyDeclaration | None = None
    model_file: Path | None = None
    vecnormalize_file: Path | None = None
    residual: tuple[str, float] | None = None
    actions: str = "deterministic"
    pixel_options: Mapping[str, int] = field(default_factory=dict)
    front_end: FrontEnd | None = None

    @property
    def env_options(self) -> dict[str, Any]:
        """The env keyword arguments of the observation the policy sees (`observation_options`):
        none for the estimate; pixels of its image size, with its pixel options."""
        return observation_options(self.image_size, self.pixel_options)

    @property
    def image_size(self) -> tuple[int, int] | None:
        """The (width, height) of the images the policy sees, where it observes pixels
        (``observation_source: pixels``, or a declared ``Dict`` observation with an image);
        None where it observes an estimate."""
        if self.front_end is not None:
            return self.front_end.image_size
        declared = self.declaration.observation_space if self.declaration else None
        if declared is not None and declared["type"] == "Dict":
            box = declared["spaces"].get("image")  # the wide image (not the end-effector crop)
            if box is not None and len(box["shape"]) == 3:
                _, height, width = box["shape"]
                return (width, height)
        if self.observation_source == PIXELS:  # an SB3 .zip only: the env's default image
            return IMAGE_SIZE
        return None

    @property
    def files(self) -> list[Path]:
        """Every file the model is made of (for provenance hashes)."""
        found = (self.metadata_file, self.weights_file, self.model_file, self.vecnormalize_file)
        return [p for p in found if p is not None]


@dataclass(frozen=True)
class LoadedPolicy:
    """A loaded policy: the SB3 policy network, its frozen observation statistics, and the
    analytic controller it is a residual on (``(base, scale)``, or None)."""

    policy: Any
    normalizer: ObservationNormalizer | None
    residual: tuple[str, float] | None = None
    sampled: bool = False
    front_end: FrontEnd | None = None

    def agent(self, name: str, description: Any, env: Any = None) -> Any:
        """The policy as an agent labelled ``name``: `SB3Policy`, or, for a residual,
        `capture_bench.agents.residual.ResidualAgent` over the base built from
        ``description``, or, behind a front end, its agent calibrated for ``env``'s scenario
        (`FrontEnd.agent`)."""
        learned = SB3Policy(self.policy, name, self.normalizer, sampled=self.sampled)
        if self.front_end is not None:
            if env is None:
                raise ValueError(f"{name}: a policy behind a front end is built for an env")
            return self.front_end.agent(learned, env, name)
        if self.residual is None:
            return learned
        from capture_bench.agents.residual import ResidualAgent, make_base

        base, scale = self.residual
        return ResidualAgent(make_base(base, description), learned, scale, name)


def find_metadata_file(directory: Path) -> Path | None:
    """The metadata file of a model directory, or None."""
    for name in METADATA_FILES:
        if (directory / name).is_file():
            return directory / name
    return None


def _zip_file(directory: Path, data: dict, meta_file: Path, required: bool) -> Path | None:
    if "model" in data and data["model"]:
        model_file = directory / str(data["model"])
    else:
        zips = sorted(directory.glob("*.zip"))
        if len(zips) != 1:
            if not required and not zips:
                return None
            found = ", ".join(p.name for p in zips) or "none"
            raise PolicyLoadError(
                f"{directory}: expected exactly one SB3 .zip (found: {found}); "
                f"or name it with key 'model' in {meta_file.name}"
            )
        model_file = zips[0]
    if not model_file.is_file():
        if not required:
            return None
        raise PolicyLoadError(f"{model_file}: model file is missing")
    return model_file


def _existing(path: Path | None) -> Path | None:
    return path if path is not None and path.is_file() else None


def read_metadata_file(meta_file: Path) -> Any:
    """A metadata file's content, parsed (JSON, or YAML by its suffix), unchecked.

    Raises:
        PolicyLoadError: the file is larger than `MAX_METADATA_BYTES` (refused before reading
            it), unreadable or not JSON/YAML.
    """
    try:
        size = meta_file.stat().st_size
        if size > MAX_METADATA_BYTES:
            raise PolicyLoadError(
                f"{meta_file}: {size / 2**20:.1f} MiB, more than the {MAX_METADATA_BYTES >> 20} "
                "MiB a metadata file may hold; refused before reading it"
            )
        text = meta_file.read_text()
        return json.loads(text) if meta_file.suffix == ".json" else yaml.safe_load(text)
    except PolicyLoadError:
        raise
    except (OSError, ValueError, yaml.YAMLError) as exc:
        reason = " ".join(str(exc).split())
        raise PolicyLoadError(f"{meta_file}: unreadable metadata ({reason})") from None


def read_metadata(directory: str | Path) -> ModelMetadata:
    """Read and validate a model directory's metadata (see module docstring); reads no model.

    Raises:
        PolicyLoadError: no directory or metadata, unreadable metadata, a bad key or value, or
            a missing file.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise PolicyLoadError(f"{directory}: no such model directory")
    meta_file = find_metadata_file(directory)
    if meta_file is None:
        raise PolicyLoadError(
            f"{directory}: no metadata file; expected one of {', '.join(METADATA_FILES)} "
            f"naming the algorithm ({', '.join(ALGORITHMS)})"
        )
    data = read_metadata_file(meta_file)
    if not isinstance(data, dict):
        raise PolicyLoadError(f"{meta_file}: expected a mapping with key 'algorithm'")
    algorithm = str(data.get("algorithm", data.get("algo", ""))).upper()
    if algorithm not in ALGORITHMS:
        raise PolicyLoadError(
            f"{meta_file}: key 'algorithm' is {data.get('algorithm')!r}; "
            f"valid: {', '.join(ALGORITHMS)}"
        )
    common: dict[str, Any] = {
        "directory": directory,
        "algorithm": algorithm,
        "metadata_file": meta_file,
        "scenario": str(data.get("scenario") or ""),
        "observation_source": str(data.get("observation_source") or ""),
        "residual": _residual(data.get("residual"), meta_file),
        "actions": _actions(data.get("actions", "deterministic"), meta_file),
        "pixel_options": _pixel_options(data.get("pixel_observation"), meta_file),
        "front_end": _front_end(data.get("front_end"), meta_file),
    }
    vecnormalize = data.get("vecnormalize")
    vecnormalize_file = directory / str(vecnormalize) if vecnormalize else None
    if "format" in data:  # the safe form
        declaration = parse_declaration(data, str(meta_file))
        weights = data.get("weights")
        if not isinstance(weights, str) or not weights or Path(weights).name != weights:
            raise PolicyLoadError(
                f"{meta_file}: key 'weights' is {weights!r}; valid: a file name in {directory}"
            )
        weights_file = directory / weights
        if not weights_file.is_file():
            raise PolicyLoadError(f"{weights_file}: weights file is missing")
        return ModelMetadata(
            **common,
            weights_file=weights_file,
            declaration=declaration,
            model_file=_zip_file(directory, data, meta_file, required=False),
            vecnormalize_file=_existing(vecnormalize_file),  # the .zip's, for trusted loading
        )
    model_file = _zip_file(directory, data, meta_file, required=True)
    if vecnormalize_file is not None and not vecnormalize_file.is_file():
        raise PolicyLoadError(f"{vecnormalize_file}: VecNormalize statistics file is missing")
    return ModelMetadata(**common, model_file=model_file, vecnormalize_file=vecnormalize_file)


ACTION_RULES = ("deterministic", "sampled")


def _actions(value: Any, meta_file: Path) -> str:
    if value not in ACTION_RULES:
        raise PolicyLoadError(
            f"{meta_file}: key 'actions' is {value!r}; valid: {', '.join(ACTION_RULES)}"
        )
    return str(value)


def _whole(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _front_end(value: Any, meta_file: Path) -> FrontEnd | None:
    """The metadata's ``front_end`` entry, checked: None, or ``{name: <one of FRONT_ENDS>,
    stack: 1-16, image_size: [width, height]}``."""
    from capture_bench.agents.marker_pose import FRONT_ENDS

    if value is None:
        return None
    valid = (
        f"null or {{name: one of {', '.join(FRONT_ENDS)}, stack: a whole number 1-16, "
        "image_size: [width, height]}"
    )
    size = value.get("image_size") if isinstance(value, dict) else None
    if not (
        isinstance(value, dict)
        and set(value) == {"name", "stack", "image_size"}
        and value["name"] in FRONT_ENDS
        and _whole(value["stack"])
        and 1 <= value["stack"] <= 16
        and isinstance(size, list)
        and len(size) == 2
        and all(_whole(x) and x > 0 for x in size)
    ):
        raise PolicyLoadError(f"{meta_file}: key 'front_end' is {value!r}; valid: {valid}")
    return FrontEnd(str(value["name"]), int(value["stack"]), (int(size[0]), int(size[1])))


def _residual(value: Any, meta_file: Path) -> tuple[str, float] | None:
    """The metadata's ``residual`` entry, checked: None, or ``{base: <name>, scale: (0, 1]}``."""
    from capture_bench.agents.residual import RESIDUAL_BASES

    if value is None:
        return None
    valid = f"null or {{base: one of {', '.join(RESIDUAL_BASES)}, scale: a number in (0, 1]}}"
    if not (
        isinstance(value, dict)
        and set(value) == {"base", "scale"}
        and value["base"] in RESIDUAL_BASES
        and isinstance(value["scale"], (int, float))
        and not isinstance(value["scale"], bool)
        and 0 < value["scale"] <= 1
    ):
        raise PolicyLoadError(f"{meta_file}: key 'residual' is {value!r}; valid: {valid}")
    return str(value["base"]), float(value["scale"])


def load_policy(metadata: ModelMetadata, trust_model: bool = False) -> LoadedPolicy:
    """Load the model of ``metadata`` on the CPU.

    The safe form is always preferred. An SB3 ``.zip`` (pickles) is loaded only with
    ``trust_model=True`` and only where there is no safe form.

    Raises:
        PolicyLoadError: refused (an SB3 ``.zip`` without ``trust_model``), or not loadable.
    """
    if metadata.declaration is not None and metadata.weights_file is not None:
        where = str(metadata.weights_file)
        policy = build_policy(metadata.declaration, str(metadata.metadata_file))
        load_weights(policy, read_weights(metadata.weights_file), where, metadata.algorithm)
        return LoadedPolicy(
            policy,
            metadata.declaration.normalization,
            metadata.residual,
            metadata.actions == "sampled",
            metadata.front_end,
        )
    if not trust_model:
        raise PolicyLoadError(
            f"{metadata.directory}: refused to load its SB3 .zip (there is no safe policy.pt): "
            + TRUST_HINT.format(directory=metadata.directory)
        )
    return load_trusted(metadata)


#: The SB3 policy classes each algorithm's ``.zip`` may hold (a Box or a Dict observation).
_POLICY_CLASS_NAMES = [
    (algorithm, name)
    for table in (POLICY_CLASSES, MULTI_INPUT_POLICY_CLASSES)
    for algorithm, (_, name) in table.items()
]


def _zip_policy_class(model_file: Path) -> tuple[str, set[str]] | None:
    """The policy class name an SB3 ``.zip`` declares and its data keys, read as JSON only
    (None if the file does not say)."""
    try:
        with zipfile.ZipFile(model_file) as archive:
            data = json.loads(archive.read("data"))
        init = str(data["policy_class"]["__init__"])
    except Exception:  # not an SB3 zip, or an unusual one: SB3's own loader will say
        return None
    match = re.search(r"<function (\w+)\.__init__", init)
    return (match.group(1), set(data)) if match else None


def _check_zip_algorithm(metadata: ModelMetadata) -> None:
    """Refuse a ``.zip`` whose policy class is not the metadata's algorithm's (before SB3 would
    fail with its own, obscure, message)."""
    assert metadata.model_file is not None
    found = _zip_policy_class(metadata.model_file)
    if found is None:
        return
    class_name, keys = found
    held = [a for a, name in _POLICY_CLASS_NAMES if name == class_name]
    if "PPO" in held:  # PPO and A2C share ActorCriticPolicy; only PPO saves a clip range
        held = ["PPO"] if "clip_range" in keys else [a for a in held if a != "PPO"]
    if metadata.algorithm not in held:
        says = held[0] if held else class_name
        raise PolicyLoadError(
            f"{metadata.metadata_file}: says algorithm {metadata.algorithm}, but "
            f"{metadata.model_file.name} holds a {says} model ({class_name}); "
            f"set 'algorithm' to {says}"
        )


def load_trusted(metadata: ModelMetadata) -> LoadedPolicy:
    """Load the SB3 ``.zip`` (and VecNormalize statistics) by unpickling them: trusted files only.

    Raises:
        PolicyLoadError: no ``.zip``, an algorithm that does not match it, or a corrupt file.
    """
    import stable_baselines3

    if metadata.model_file is None:
        raise PolicyLoadError(f"{metadata.directory}: no SB3 .zip to load")
    check_archive(metadata.model_file, require_zip=False)  # sizes, before anything reads it
    _check_zip_algorithm(metadata)
    if metadata.algorithm == "TQC":
        try:
            import sb3_contrib
        except ImportError:
            raise PolicyLoadError(
                f"{metadata.model_file}: TQC needs sb3-contrib; pip install sb3-contrib"
            ) from None
        algorithm_class = sb3_contrib.TQC
    else:
        algorithm_class = getattr(stable_baselines3, metadata.algorithm)
    try:
        model = algorithm_class.load(str(metadata.model_file), device="cpu")
    except Exception as exc:  # SB3 raises many kinds on a bad file; all mean "cannot load"
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise PolicyLoadError(
            f"{metadata.model_file}: not a loadable {metadata.algorithm} model ({reason})"
        ) from None
    model.policy.set_training_mode(False)
    return LoadedPolicy(
        model.policy,
        _load_vecnormalize(metadata),
        metadata.residual,
        metadata.actions == "sampled",
        metadata.front_end,
    )


def _load_vecnormalize(metadata: ModelMetadata) -> ObservationNormalizer | None:
    """The frozen statistics of the ``.zip``'s VecNormalize pickle (None if it has none)."""
    if metadata.vecnormalize_file is None:
        return None
    import pickle

    try:
        with open(metadata.vecnormalize_file, "rb") as handle:
            vecnormalize = pickle.load(handle)
        normalizer = ObservationNormalizer.from_vecnormalize(vecnormalize)
    except Exception as exc:  # a bad pickle can raise almost anything
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise PolicyLoadError(
            f"{metadata.vecnormalize_file}: not loadable VecNormalize statistics ({reason})"
        ) from None
    return normalizer


def _describe(space: Any) -> str:
    if hasattr(space, "spaces") and isinstance(space.spaces, dict):  # a Dict: its parts' shapes
        parts = ", ".join(f"{k}: {_describe(v)}" for k, v in space.spaces.items())
        return f"Dict({parts})"
    shape = getattr(space, "shape", None)
    return f"{type(space).__name__}{tuple(shape) if shape is not None else ''}"


def _same_box(a: Any, b: Any) -> bool:
    if type(a).__name__ != type(b).__name__ or getattr(a, "shape", None) != getattr(b, "shape", 0):
        return False
    if hasattr(a, "low") and hasattr(b, "low"):
        return bool(np.allclose(a.low, b.low) and np.allclose(a.high, b.high))
    return a == b


def check_spaces(model: Any, observation_space: Any, action_space: Any, where: str) -> None:
    """Raise `PolicyLoadError` unless the model's spaces equal the environment's.

    Args:
        model: a loaded SB3 policy (or model).
        observation_space, action_space: the environment's spaces.
        where: names the model and the environment in the message.
    """
    for kind, ours, theirs in (
        ("observation", model.observation_space, observation_space),
        ("action", model.action_space, action_space),
    ):
        pixels = [type(space).__name__ == "Dict" for space in (ours, theirs)]
        if kind == "observation" and pixels[0] != pixels[1]:
            sees, needs = ("the camera's pixels", "estimate") if pixels[0] else (
                "the estimate", "pixels")  # fmt: skip
            fix = "observation_source='pixels'" if pixels[0] else "an estimator source"
            raise PolicyLoadError(
                f"{where}: the model observes {sees} ({_describe(ours)}), the environment gives "
                f"the {needs} ({_describe(theirs)}); make the environment with {fix}"
            )
        if not _same_box(ours, theirs):
            hint = (
                "; make the environment with the image_size and pixel options of the model's "
                "card (its pixel_observation: frame_stack, ee_crop, ...)"
                if all(pixels)
                else ""
            )
            raise PolicyLoadError(
                f"{where}: model {kind} space {_describe(ours)} does not match the "
                f"environment's {_describe(theirs)}{hint}"
            )


def check_model_spaces(loaded: LoadedPolicy, env: Any, where: str) -> None:
    """`check_spaces` of a loaded policy on ``env``; behind a front end, ``env`` gives what
    the front end reads (`FrontEnd.check`) and the network reads the front end's vector."""
    observation_space = env.observation_space
    if loaded.front_end is not None:
        from capture_bench.agents.marker_pose import front_end_space

        loaded.front_end.check(env, where)
        observation_space = front_end_space(loaded.front_end.stack)
    check_spaces(loaded.policy, observation_space, env.action_space, where)


class SB3Policy:
    """A loaded SB3 policy behind the
    [`capture_bench.agents.protocol.Agent`][capture_bench.agents.protocol.Agent] protocol.

    Args:
        policy: the SB3 policy network (``model.policy`` or `load_policy`'s); its
            ``predict`` does the work, exactly as ``model.predict`` would.
        name: label for reports.
        normalizer: frozen observation statistics applied to observations first, or None.
        sampled: act with sampled actions whatever ``predict`` is asked (a model card that
            declares ``actions: sampled``; torch's generator, which evaluation seeds per
            episode).
    """

    privileged = False

    def __init__(
        self,
        policy: Any,
        name: str = "sb3",
        normalizer: ObservationNormalizer | None = None,
        sampled: bool = False,
    ) -> None:
        from stable_baselines3.common.distributions import DiagGaussianDistribution
        from stable_baselines3.common.policies import ActorCriticPolicy

        self.policy = policy
        self.name = name
        self.normalizer = normalizer
        self.sampled = sampled
        # Whether the deterministic action is the action net's output (the Gaussian's mean).
        self._mean_is_action = isinstance(policy, ActorCriticPolicy) and (
            type(policy.action_dist) is DiagGaussianDistribution
        )

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3's ``predict``: observation (16,) (or a pixel observation's dict) -> ``(action (3,),
        state)``; a batch (N, 16) goes through ``policy.predict`` as SB3 gives it (torch rounds a
        row of a batched product by the batch's height, so a row's action can differ in its last
        bits from the same observation's alone)."""
        deterministic = deterministic and not self.sampled
        if self.normalizer is not None and not isinstance(observation, dict):  # a Box's only
            observation = self.normalizer.normalize_obs(observation)
        obs = np.asarray(observation)
        if deterministic and state is None and obs.shape == self.policy.observation_space.shape:
            return self._deterministic_action(obs), None
        action, state = self.policy.predict(
            observation, state=state, episode_start=episode_start, deterministic=deterministic
        )
        return np.asarray(action, dtype=np.float32), state

    def _deterministic_action(self, obs: np.ndarray) -> np.ndarray:
        """``policy.predict(obs, deterministic=True)`` for one Box observation, without its
        per-call checks and, for actor-critic policies, without building the action distribution
        only to take its mode: the mean of a diagonal Gaussian is the action net's output.
        The same torch operations on the same numbers, so the same action (tested).
        """
        return self._deterministic_actions(obs[None]).reshape(self.policy.action_space.shape)

    def _deterministic_actions(self, obs: np.ndarray) -> np.ndarray:
        """`_deterministic_action` of each row of ``obs`` (already normalised), in one
        forward pass of N rows."""
        import torch
        from stable_baselines3.common.policies import BasePolicy

        policy = self.policy
        with torch.no_grad():
            tensor = torch.as_tensor(obs, dtype=torch.float32)
            if self._mean_is_action:
                # the actor's features, shared extractor or not (BasePolicy's method)
                features = BasePolicy.extract_features(policy, tensor, policy.pi_features_extractor)
                actions = policy.action_net(policy.mlp_extractor.forward_actor(features))
            else:
                actions = policy._predict(tensor, deterministic=True)
        action = actions.numpy().reshape(obs.shape[0], *policy.action_space.shape)
        if policy.squash_output:  # as BasePolicy.predict does for a Box action space
            action = policy.unscale_action(action)
        else:
            action = np.clip(action, policy.action_space.low, policy.action_space.high)
        return np.asarray(action, dtype=np.float32)

    def predict_rows(self, observations: np.ndarray) -> np.ndarray:
        """The deterministic action of each of N observations, shape (N, 16) -> (N, 3), each
        row bit for bit what ``predict`` gives that observation alone, in one batched forward
        pass (`capture_bench.agents.row_exact`; row by row where a layer has no row-exact
        batched form). For a model declaring sampled actions, ``predict`` of each row in turn
        (torch's one generator draws in row order)."""
        from capture_bench.agents.row_exact import row_exact_layers

        if isinstance(observations, dict):  # pixels: a convolution's rows depend on the batch
            n = len(next(iter(observations.values())))
            rows = ({key: value[i] for key, value in observations.items()} for i in range(n))
            return np.stack([self.predict(row)[0] for row in rows])
        obs = np.asarray(observations)
        if self.sampled:
            return np.stack([self.predict(row)[0] for row in obs])
        if self.normalizer is not None:
            obs = self.normalizer.normalize_obs(obs)
        with row_exact_layers(self.policy) as exact:
            if exact:
                return self._deterministic_actions(obs)
        return np.stack([self._deterministic_action(row) for row in obs])

    def reset(self) -> None:
        """Nothing to forget: recurrent state, if any, is passed through ``predict``."""


def load_sb3_policy(
    directory: str | Path, env: Any, name: str | None = None, trust_model: bool = False
) -> Any:
    """Load the model in ``directory`` (safely; see `load_policy`) and check it fits
    ``env``; an `SB3Policy`, a `capture_bench.agents.residual.ResidualAgent`
    for a residual, or a `capture_bench.agents.marker_pose.MarkerPoseAgent` for a policy behind
    a front end.

    Args:
        directory: the model directory.
        env: the environment it will act in (its spaces are checked).
        name: label for reports (default: the directory's name).
        trust_model: allow unpickling an SB3 ``.zip`` where the directory has no safe form.

    Raises:
        PolicyLoadError: bad metadata, refused or corrupt model, or mismatched spaces.
    """
    metadata = read_metadata(directory)
    loaded = load_policy(metadata, trust_model=trust_model)
    label = name or metadata.directory.name
    check_model_spaces(loaded, env, str(metadata.directory))
    return loaded.agent(label, env.unwrapped.description, env)
