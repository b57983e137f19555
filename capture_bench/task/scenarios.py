"""Scenarios: YAML files under ``configs/scenarios/`` validated once into typed objects.

Every quantity has a unit in its name or its docstring; degrees appear only here (YAML) and are
converted to radians by the consumers' ``*_rad`` properties. A bad file raises
:class:`ConfigError` naming the file, the key, the bad value and what would be valid.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from capture_bench.paths import config_dir
from capture_bench.sensing.sources import SOURCES

CONFIG_DIR = config_dir()  # configs/: see capture_bench.paths
SCENARIO_DIR = CONFIG_DIR / "scenarios"
POSITIVE = (0.0, math.inf, False)  # (low, high, low inclusive)
NON_NEGATIVE = (0.0, math.inf, True)


OBSERVATION_SOURCES = SOURCES


class ConfigError(ValueError):
    """A configuration file or value is invalid; the message says where and what is valid."""


def _f(
    default: Any,
    doc: str,
    bounds: tuple[float, float, bool] | None = None,
    choices: tuple[str, ...] | None = None,
) -> Any:
    """A dataclass field with its documentation and validation rule."""
    meta = {"doc": doc, "bounds": bounds, "choices": choices}
    if isinstance(default, (list, tuple)):
        return field(default_factory=lambda: tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class ControlConfig:
    period: float = _f(0.05, "nominal control period t_s, s", POSITIVE)
    period_jitter: float = _f(
        0.0, "real period drawn uniformly in t_s*(1 +- jitter); 0-0.9", (0.0, 0.9, True)
    )
    episode_limit: float = _f(10.0, "episode time limit, s (simulated time)", POSITIVE)


@dataclass(frozen=True)
class CameraConfig:
    position: tuple[float, float, float] = _f((0.45, -1.2, 0.40), "image-plane centre, global, m")
    look_at: tuple[float, float, float] = _f(
        (0.45, 0.0, 0.40), "point the y-axis passes through, global, m"
    )
    focal_length: float = _f(0.008, "focal length f, m", POSITIVE)
    pixel_pitch: float = _f(3.75e-6, "pixel pitch, m", POSITIVE)
    resolution: tuple[int, int] = _f((1280, 960), "sensor width, height, px")
    noise_px: float = _f(1.0, "Gaussian image noise sigma, px", NON_NEGATIVE)
    dropout: float = _f(0.0, "probability that a frame is lost, 0-1", (0.0, 1.0, True))
    latency_frames: int = _f(0, "whole frames of latency", NON_NEGATIVE)


@dataclass(frozen=True)
class EstimatorConfig:
    source: str = _f("ekf", "observation source", choices=SOURCES)
    sigma_acceleration: float = _f(0.01, "EKF process noise, m/s^2", POSITIVE)
    sigma_angular_acceleration: float = _f(0.01, "EKF process noise, rad/s^2", POSITIVE)


@dataclass(frozen=True)
class TargetConfig:
    motion: str = _f("drift", "true motion", choices=("drift", "circular", "tumbling", "evasive"))
    feature_points: str = _f(
        "non_coplanar", "marker layout", choices=("non_coplanar", "coplanar_square")
    )
    initial_offset: tuple[float, float] = _f(
        (0.25, 0.35), "capture point to home end-effector at t=0, m"
    )
    speed: tuple[float, float] = _f(
        (0.005, 0.05), "drift speed of the centre (initial speed for evasive), m/s"
    )
    tumble_rate_deg: tuple[float, float] = _f((0.0, 0.0), "tumble rate, deg/s")
    capture_offset: tuple[float, float] = _f(
        (0.0, 0.0), "capture point distance from the centre of rotation, m"
    )
    circle_radius: tuple[float, float] = _f((0.05, 0.15), "circular path radius, m")
    circle_speed: tuple[float, float] = _f((0.01, 0.04), "speed along the circle, m/s")
    jink_interval: tuple[float, float] = _f(
        (0.5, 1.5), "time between acceleration changes (evasive), s"
    )
    jink_acceleration: tuple[float, float] = _f(
        (0.005, 0.03), "acceleration magnitude (evasive), m/s^2"
    )


@dataclass(frozen=True)
class SeedConfig:
    evaluation_start: int = _f(1_000_000, "first published evaluation seed", NON_NEGATIVE)
    evaluation_count: int = _f(100, "number of published evaluation seeds", POSITIVE)
    training_start: int = _f(0, "first seed training may draw from", NON_NEGATIVE)
    training_count: int = _f(1_000_000, "number of training seeds", POSITIVE)


@dataclass(frozen=True)
class Scenario:
    """One benchmark scenario (a YAML file under ``configs/scenarios/``)."""

    name: str = _f("custom", "scenario name; the env ID is CaptureBench/<Name>-v0")
    description: str = _f("", "one line for people")
    capture_tolerance: float = _f(0.001, "epsilon of eq. 20 (each component), m", POSITIVE)
    lost_after: float = _f(
        0.5,
        "seconds without a usable frame, or with the target out of reach, before failing",
        POSITIVE,
    )
    control: ControlConfig = field(default_factory=ControlConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    target: TargetConfig = field(default_factory=TargetConfig)
    seeds: SeedConfig = field(default_factory=SeedConfig)

    @property
    def env_id(self) -> str:
        return f"CaptureBench/{self.name.title().replace('_', '')}-v0"

    @property
    def evaluation_seeds(self) -> list[int]:
        """The published evaluation seeds (disjoint from the training range)."""
        return list(
            range(
                self.seeds.evaluation_start,
                self.seeds.evaluation_start + self.seeds.evaluation_count,
            )
        )

    @property
    def training_seeds(self) -> range:
        return range(
            self.seeds.training_start, self.seeds.training_start + self.seeds.training_count
        )

    def estimator_settings(self) -> dict[str, float]:
        """What the estimator assumes (pixel noise, process noise), as the keyword arguments of
        ``TargetEstimator`` and ``BatchedTargetEstimator``."""
        return {
            "noise_px": self.camera.noise_px,
            "sigma_acceleration": self.estimator.sigma_acceleration,
            "sigma_angular_acceleration": self.estimator.sigma_angular_acceleration,
        }

    def replace(self, **sections: Any) -> Scenario:
        """A copy with some fields replaced, e.g. ``replace(estimator={"source": "truth"})``;
        nested mappings are validated like YAML."""
        data = dataclasses.asdict(self)
        for key, value in sections.items():
            if isinstance(value, dict) and isinstance(data.get(key), dict):
                data[key].update(value)
            else:
                data[key] = value
        return _build(Scenario, data, source="<override>", prefix="")


def scenario_files() -> list[Path]:
    """Every ``*.yaml`` file under :data:`SCENARIO_DIR`, valid or not, sorted by name."""
    return sorted(SCENARIO_DIR.glob("*.yaml"))


def list_scenarios() -> list[str]:
    """Names of the shipped scenarios that load, sorted. An invalid file is left out here (it
    breaks only itself); :func:`invalid_scenarios` says which and why."""
    invalid = invalid_scenarios()
    return [p.stem for p in scenario_files() if p.stem not in invalid]


def invalid_scenarios() -> dict[str, str]:
    """The shipped scenario files that do not load: ``{name: the ConfigError message}`` (the
    message names the file, the key and what is valid); ``load_scenario(name)`` raises it."""
    invalid = {}
    for path in scenario_files():
        try:
            load_scenario(path)
        except ConfigError as exc:
            invalid[path.stem] = str(exc)
    return invalid


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load and validate a shipped scenario by name, or any scenario YAML by path.

    Raises:
        ConfigError: no such scenario, or the file is invalid (the message names the file, the
            key, the bad value and what would be valid).
    """
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = SCENARIO_DIR / f"{name_or_path}.yaml"
        if not path.is_file():
            valid = ", ".join(list_scenarios()) or "none"
            raise ConfigError(f"unknown scenario {str(name_or_path)!r}; valid: {valid}")
    if not path.is_file():
        raise ConfigError(f"{path}: no such scenario file")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML: {' '.join(str(exc).split())}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of scenario keys, got {type(data).__name__}")
    data.setdefault("name", path.stem)
    scenario = _build(Scenario, data, source=str(path), prefix="")
    return scenario


def _build(cls: type, data: dict[str, Any], source: str, prefix: str) -> Any:
    """Validate a mapping against dataclass ``cls`` and build it (recursively)."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{source}: unknown key {prefix + unknown[0]!r}; valid keys: {', '.join(fields)}"
        )
    values = {}
    for name, value in data.items():
        key, kind, meta = prefix + name, hints[name], fields[name].metadata
        if isinstance(kind, type) and dataclasses.is_dataclass(kind):
            if not isinstance(value, dict):
                raise ConfigError(f"{source}: key {key!r} must be a mapping, got {value!r}")
            values[name] = _build(kind, value, source, key + ".")
        else:
            values[name] = _check_value(value, kind, meta, source, key)
    return cls(**values)


def _check_value(value: Any, kind: Any, meta: Any, source: str, key: str) -> Any:
    where = f"{source}: key {key!r}"
    if typing.get_origin(kind) is tuple:
        item_types = typing.get_args(kind)
        if not isinstance(value, (list, tuple)) or len(value) != len(item_types):
            raise ConfigError(f"{where}: {value!r} should be a list of {len(item_types)} numbers")
        items = tuple(_number(v, t, where) for v, t in zip(value, item_types))
        if len(items) == 2 and item_types[0] is float and items[0] > items[1]:
            raise ConfigError(f"{where}: range {list(value)} has low > high; write [low, high]")
        return items
    if kind is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: {value!r} should be a string")
        choices = meta.get("choices")
        if choices and value not in choices:
            raise ConfigError(
                f"{where}: {value!r} is not valid; choose one of {', '.join(choices)}"
            )
        return value
    number = _number(value, kind, where)
    bounds = meta.get("bounds")
    if bounds is not None:
        low, high, inclusive = bounds
        if not ((number >= low if inclusive else number > low) and number <= high):
            rule = f"{'>=' if inclusive else '>'} {low:g}" + (
                f" and <= {high:g}" if high < math.inf else ""
            )
            raise ConfigError(f"{where}: {value!r} is out of range; expected a number {rule}")
    return number


def _number(value: Any, kind: Any, where: str) -> Any:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where}: {value!r} should be a number")
    if kind is int:
        if float(value) != int(value):
            raise ConfigError(f"{where}: {value!r} should be a whole number")
        return int(value)
    if not math.isfinite(value):
        raise ConfigError(f"{where}: {value!r} should be a finite number")
    return float(value)
