"""Scenarios: YAML files under ``configs/scenarios/`` validated once into typed objects.

Every quantity has a unit in its name or its docstring; degrees appear only here (YAML) and are
converted to radians by the consumers' ``*_rad`` properties. A bad file raises
[`ConfigError`][capture_bench.task.scenarios.ConfigError] naming the file, the key, the bad value
and what would be valid.

Every number has a finite valid range, so that no value accepted here can make an episode
allocate without bound, loop without end or fail after it starts; `_checked` adds the rules
that tie keys together (the steps of an episode, the camera's view direction, the capture box
against the target's start, the evasive target's manoeuvres).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from capture_bench.paths import config_dir
from capture_bench.sensing.calibration import CalibrationSpread, Distortion
from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.detection_noise import detection_sigma, rms_speed
from capture_bench.sensing.ekf import NOISE_FLOOR_PX
from capture_bench.sensing.sources import SOURCES
from capture_bench.sim.target_motion import MAX_JINKS
from capture_bench.validation import (
    IDENTIFIER,
    IDENTIFIER_TEXT,
    ConfigError,
    Rule,
    check_mapping,
    is_file,
    read_mapping,
)

CONFIG_DIR = config_dir()  # configs/: see capture_bench.paths
SCENARIO_DIR = CONFIG_DIR / "scenarios"
POSITIVE = (0.0, math.inf, False)  # (low, high, low inclusive)
NON_NEGATIVE = (0.0, math.inf, True)

#: The most control steps an episode may have, ``control.episode_limit`` over the shortest real
#: period ``control.period (1 - control.period_jitter)``: every step's period is drawn at reset.
MAX_EPISODE_STEPS = 100_000
#: The largest ``target.initial_offset``, m: no point the arm reaches inside its joint limits is
#: farther than 1.37 m from the home end-effector (joint 1 at +-170 deg, the arm stretched
#: behind the column), so a larger offset could never start in reach.
MAX_INITIAL_OFFSET = 1.4
#: The closest ``camera.look_at`` may be to ``camera.position``, m (the view direction is their
#: difference).
MIN_LOOK_DISTANCE = 0.001
#: The smallest angle between the view direction and the vertical, rad: the camera's z-axis is
#: the global z made perpendicular to the view, undefined when looking straight up or down.
MIN_VIEW_TILT = 1e-6


OBSERVATION_SOURCES = SOURCES
#: How the camera makes its frames (``camera.mode``).
CAMERA_MODES = ("analytic", "rendered")


def _f(
    default: Any,
    doc: str,
    bounds: tuple[float, float, bool] | None = None,
    choices: tuple[str, ...] | None = None,
    identifier: bool = False,
) -> Any:
    """A dataclass field with its documentation and validation rule (``bounds``: (low, high, low
    inclusive) of a number or of each item of a list; ``identifier``: a string that must match
    `IDENTIFIER`)."""
    meta = {"doc": doc, "bounds": bounds, "choices": choices, "identifier": identifier}
    if isinstance(default, (list, tuple)):
        return field(default_factory=lambda: tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class ControlConfig:
    period: float = _f(0.05, "nominal control period t_s, s", (0.001, 1.0, True))
    period_jitter: float = _f(
        0.0, "real period drawn uniformly in t_s*(1 +- jitter); 0-0.9", (0.0, 0.9, True)
    )
    episode_limit: float = _f(
        10.0,
        "episode time limit, s (simulated time); at most 100,000 control steps of the shortest"
        " real period",
        (0.0, 3600.0, False),
    )


@dataclass(frozen=True)
class CameraConfig:
    position: tuple[float, float, float] = _f(
        (0.45, -1.2, 0.40), "image-plane centre, global, m", (-10.0, 10.0, True)
    )
    look_at: tuple[float, float, float] = _f(
        (0.45, 0.0, 0.40),
        "point the y-axis passes through, global, m; at least 1 mm from position, not straight"
        " above or below it",
        (-10.0, 10.0, True),
    )
    focal_length: float = _f(0.008, "focal length f, m", (0.0001, 1.0, True))
    pixel_pitch: float = _f(3.75e-6, "pixel pitch, m", (1e-7, 1e-4, True))
    resolution: tuple[int, int] = _f((1280, 960), "sensor width, height, px", (1, 8192, True))
    noise_px: float = _f(1.0, "Gaussian image noise sigma, px", (0.0, 100.0, True))
    dropout: float = _f(0.0, "probability that a frame is lost, 0-1", (0.0, 1.0, True))
    latency_frames: int = _f(0, "whole frames of latency", (0, 100, True))
    mode: str = _f(
        "analytic",
        "analytic: the markers' centres projected by eq. 2 plus noise_px; rendered: pybullet"
        " renders the camera's image and the markers are found in its pixels (noise_px unused)",
        choices=CAMERA_MODES,
    )
    marker_radius: float = _f(
        0.005,
        "sphere marker radius (rendered), m; larger ones hide each other more",
        (0.0, 0.05, False),
    )
    target_block: bool = _f(False, "a grey block between the markers that can hide them (rendered)")
    light_direction: tuple[float, float, float] = _f(
        (0.0, 0.0, 0.0),
        "where the light comes from, global (rendered; all 0: from the lens)",
        (-10.0, 10.0, True),
    )
    light_intensity: float = _f(1.0, "diffuse light, 1 = default (rendered)", (0.0, 10.0, True))
    image_noise: float = _f(
        0.0,
        "sensor noise sigma added to each pixel, grey levels 0-255 (rendered)",
        (0.0, 255.0, True),
    )
    exposure: float = _f(
        0.0,
        "exposure time, s: motion blur over [t - exposure, t] (rendered; 0: none)",
        (0.0, 1.0, True),
    )
    psf_sigma: float = _f(
        0.0,
        "optics blur: standard deviation of the Gaussian point-spread function the image is"
        " convolved with before the sensor noise, px, 0-5 (rendered; 0: none)",
        (0.0, 5.0, True),
    )
    # The lens and the calibration error (capture_bench.sensing.calibration): the estimator
    # knows the nominal values, the episode's true camera deviates from them.
    distortion_k1: float = _f(
        0.0,
        "radial distortion k1 of the lens, known to the estimator, OpenCV's convention (< 0: "
        "barrel)",
        (-1.0, 1.0, True),
    )
    distortion_k2: float = _f(0.0, "radial distortion k2, OpenCV's convention", (-1.0, 1.0, True))
    distortion_p1: float = _f(
        0.0, "tangential distortion p1, OpenCV's convention", (-0.1, 0.1, True)
    )
    distortion_p2: float = _f(
        0.0, "tangential distortion p2, OpenCV's convention", (-0.1, 0.1, True)
    )
    calibration_focal: float = _f(
        0.0,
        "calibration error: sigma of the true focal length's relative error, drawn per episode "
        "(0: none)",
        (0.0, 0.1, True),
    )
    calibration_principal_px: float = _f(
        0.0,
        "calibration error: sigma of the principal point's error on each axis, px, per episode",
        (0.0, 50.0, True),
    )
    calibration_k1: float = _f(
        0.0,
        "calibration error: sigma of the true k1 minus distortion_k1, per episode",
        (0.0, 0.5, True),
    )
    calibration_rotation_deg: float = _f(
        0.0,
        "calibration error: sigma of the camera's orientation error about each camera axis, deg, "
        "per episode",
        (0.0, 5.0, True),
    )
    calibration_position: float = _f(
        0.0,
        "calibration error: sigma of the camera's position error along each axis, m, per episode",
        (0.0, 0.05, True),
    )

    def model(self) -> CameraModel:
        """The camera's geometry: looking from ``position`` at ``look_at`` with these
        intrinsics."""
        return CameraModel.looking_at(
            self.position,
            self.look_at,
            focal_length=self.focal_length,
            pixel_pitch=self.pixel_pitch,
            resolution=self.resolution,
        )

    @property
    def calibration_rotation_rad(self) -> float:
        """``calibration_rotation_deg`` in radians."""
        return math.radians(self.calibration_rotation_deg)

    def calibration_spread(self) -> CalibrationSpread:
        """The nominal lens and the calibration error's spread these keys give."""
        return CalibrationSpread(
            distortion=Distortion(
                self.distortion_k1, self.distortion_k2, self.distortion_p1, self.distortion_p2
            ),
            focal=self.calibration_focal,
            principal=self.calibration_principal_px,
            k1=self.calibration_k1,
            rotation=self.calibration_rotation_rad,
            position=self.calibration_position,
        )


@dataclass(frozen=True)
class EstimatorConfig:
    source: str = _f("ekf", "observation source", choices=SOURCES)
    sigma_acceleration: float = _f(0.01, "EKF process noise, m/s^2", (0.0, 100.0, False))
    sigma_angular_acceleration: float = _f(0.01, "EKF process noise, rad/s^2", (0.0, 100.0, False))
    min_init_markers: int = _f(
        4,
        "fewest markers of a frame that may start the filter: 4 (photogrammetry) or 3 (also P3P)",
        (3, 4, True),
    )


@dataclass(frozen=True)
class TargetConfig:
    motion: str = _f("drift", "true motion", choices=("drift", "circular", "tumbling", "evasive"))
    feature_points: str = _f(
        "non_coplanar", "marker layout", choices=("non_coplanar", "coplanar_square")
    )
    initial_offset: tuple[float, float] = _f(
        (0.25, 0.35),
        "capture point to home end-effector at t=0, m; low above sqrt(3) capture_tolerance",
        (0.0, MAX_INITIAL_OFFSET, True),
    )
    speed: tuple[float, float] = _f(
        (0.005, 0.05),
        "drift speed of the centre (initial speed for evasive), m/s",
        (0.0, 1.0, True),
    )
    tumble_rate_deg: tuple[float, float] = _f((0.0, 0.0), "tumble rate, deg/s", (0.0, 360.0, True))
    capture_offset: tuple[float, float] = _f(
        (0.0, 0.0), "capture point distance from the centre of rotation, m", (0.0, 1.0, True)
    )
    circle_radius: tuple[float, float] = _f(
        (0.05, 0.15), "circular path radius, m", (0.001, 1.0, True)
    )
    circle_speed: tuple[float, float] = _f(
        (0.01, 0.04), "speed along the circle, m/s", (0.0, 1.0, True)
    )
    jink_interval: tuple[float, float] = _f(
        (0.5, 1.5),
        "time between acceleration changes (evasive), s; at most 100,000 in an episode",
        (0.001, 3600.0, True),
    )
    jink_acceleration: tuple[float, float] = _f(
        (0.005, 0.03), "acceleration magnitude (evasive), m/s^2", (0.0, 10.0, True)
    )


@dataclass(frozen=True)
class CaptureConfig:
    hold: float = _f(
        0.3,
        "how long the envelope (eq. 20 and v_max) must hold without a break for a capture, s (a"
        " gripper closing; 0: the first instant it holds, as in the paper; less than"
        " control.episode_limit)",
        NON_NEGATIVE,
    )
    v_max: float | None = _f(
        0.05,
        "largest instantaneous speed of the end-effector relative to the capture point while eq."
        " 20 holds, m/s, tested along the arc (soft capture; null: no bound, the paper's eq. 20)",
        (0.0, 10.0, False),
    )


@dataclass(frozen=True)
class SeedConfig:
    evaluation_start: int = _f(1_000_000, "first published evaluation seed", NON_NEGATIVE)
    evaluation_count: int = _f(
        100, "number of published evaluation seeds (listed in every report)", (0, 100_000, False)
    )
    training_start: int = _f(0, "first seed training may draw from", NON_NEGATIVE)
    training_count: int = _f(1_000_000, "number of training seeds", POSITIVE)
    validation_count: int = _f(
        1_000,
        "number of validation seeds, right after the evaluation seeds: training-time evaluation,"
        " model selection and tuning use these, never an evaluation seed",
        (0, 100_000, False),
    )


@dataclass(frozen=True)
class Scenario:
    """One benchmark scenario (a YAML file under ``configs/scenarios/``)."""

    name: str = _f(
        "custom",
        "scenario name (default: the file name); the env ID is CaptureBench/<Name>-v1",
        identifier=True,
    )
    description: str = _f("", "one line for people")
    capture_tolerance: float = _f(
        0.01,
        "epsilon of eq. 20 (each component), m (the paper's: 0.001); sqrt(3) epsilon below"
        " target.initial_offset's low",
        (0.0, 0.1, False),
    )
    lost_after: float = _f(
        0.5,
        "seconds without a usable frame, or with the target out of reach, before failing",
        POSITIVE,
    )
    ranked: bool = _f(
        True,
        "whether the scenario counts in the leaderboard's ranking; false: reported in its own"
        " table (the paper's eq. 20 as published)",
    )
    capture: CaptureConfig = field(default_factory=CaptureConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    target: TargetConfig = field(default_factory=TargetConfig)
    seeds: SeedConfig = field(default_factory=SeedConfig)

    @property
    def env_id(self) -> str:
        return f"CaptureBench/{self.name.title().replace('_', '')}-v1"

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
        """The seeds ``train.py`` draws training episodes from."""
        return range(
            self.seeds.training_start, self.seeds.training_start + self.seeds.training_count
        )

    @property
    def validation_seeds(self) -> range:
        """The ``validation_count`` seeds right after the published evaluation seeds: for
        training-time evaluation, best-model selection and tuning (DESIGN.md's third range)."""
        start = self.seeds.evaluation_start + self.seeds.evaluation_count
        return range(start, start + self.seeds.validation_count)

    def estimator_settings(self) -> dict[str, float]:
        """What the estimator assumes (pixel noise, process noise, how it may start), as the
        keyword arguments of ``TargetEstimator``. The pixel noise is ``noise_px`` with the
        analytic camera (the EKF floors it at ``NOISE_FLOOR_PX``), and with the rendered one the
        detector's centroid error that the camera's blur, noise and exposure make, measured
        (`rendered_detection_sigma`), with no floor."""
        rendered = self.camera.mode == "rendered"
        return {
            "noise_px": self.rendered_detection_sigma() if rendered else self.camera.noise_px,
            "sigma_acceleration": self.estimator.sigma_acceleration,
            "sigma_angular_acceleration": self.estimator.sigma_angular_acceleration,
            "min_init_markers": self.estimator.min_init_markers,
            "noise_floor_px": 0.0 if rendered else NOISE_FLOOR_PX,
        }

    def rendered_detection_sigma(self) -> float:
        """The rendered camera's detection error, RMS per axis, px: `detection_sigma` of the
        camera's ``psf_sigma``, ``image_noise`` and ``exposure`` and the target's RMS speed
        (``circle_speed`` on a circle, else ``speed``: a drift's, an evasive target's at the
        start)."""
        cam, target = self.camera, self.target
        low, high = target.circle_speed if target.motion == "circular" else target.speed
        speed = rms_speed(low, high)
        return detection_sigma(cam.psf_sigma, cam.image_noise, cam.exposure, speed)

    def replace(self, **sections: Any) -> Scenario:
        """A copy with some fields replaced, e.g. ``replace(estimator={"source": "truth"})``;
        nested mappings are validated like YAML."""
        data = dataclasses.asdict(self)
        for key, value in sections.items():
            if isinstance(value, dict) and isinstance(data.get(key), dict):
                data[key].update(value)
            else:
                data[key] = value
        return _checked(_build(Scenario, data, source="<override>", prefix=""), "<override>")


def with_settings(scenario: Scenario, settings: Sequence[str]) -> Scenario:
    """``scenario`` with each ``SECTION.KEY=VALUE`` of ``settings`` set (the value read as
    YAML), validated like a file; ``ConfigError`` (one line) naming a bad item or key."""
    sections: dict[str, dict[str, Any]] = {}
    for item in settings:
        name, sep, text = item.partition("=")
        section, dot, key = name.partition(".")
        if not sep or not dot or not section or not key:
            raise ConfigError(f"setting {item!r} is not valid; expected SECTION.KEY=VALUE")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError:
            raise ConfigError(f"setting {item!r}: the value is not valid YAML") from None
        sections.setdefault(section, {})[key] = value
    return scenario.replace(**sections) if sections else scenario


def scenario_files() -> list[Path]:
    """Every ``*.yaml`` file under `SCENARIO_DIR`, valid or not, sorted by name."""
    return sorted(SCENARIO_DIR.glob("*.yaml"))


def list_scenarios(camera: str | None = None) -> list[str]:
    """Names of the shipped scenarios that load, sorted; with ``camera``, those whose
    ``camera.mode`` is that. An invalid file is left out here (it breaks only itself);
    [`invalid_scenarios`][capture_bench.task.scenarios.invalid_scenarios] says which and why."""
    invalid = invalid_scenarios()
    names = [p.stem for p in scenario_files() if p.stem not in invalid]
    if camera is None:
        return names
    return [name for name in names if load_scenario(name).camera.mode == camera]


def invalid_scenarios() -> dict[str, str]:
    """The shipped scenario files that do not load: ``{name: the ConfigError message}`` (the
    message names the file, the key and what is valid; a file whose name is not a valid scenario
    name, `IDENTIFIER`, is one of them);
    ``load_scenario(name)`` raises it."""
    invalid = {}
    for path in scenario_files():
        try:
            _check_file_name(path, "a scenario under its folder is used by its file name")
            load_scenario(path)
        except ConfigError as exc:
            invalid[path.stem] = str(exc)
    return invalid


#: ``X`` + this suffix names the truth-fed twin of shipped scenario ``X`` (`truth_twin`).
TRUTH_SUFFIX = "_truth"


def truth_twin(scenario: Scenario) -> Scenario:
    """The scenario fed the true target state: ``<name>_truth``, the same in every key but
    ``estimator.source`` (``truth``), so the same targets, published seeds and capture rule."""
    return scenario.replace(name=scenario.name + TRUTH_SUFFIX, estimator={"source": "truth"})


def truth_twin_base(name: str) -> str | None:
    """The shipped scenario whose truth-fed twin ``name`` is (``paper`` for ``paper_truth``),
    where no shipped file is named ``name``; None otherwise."""
    if not name.endswith(TRUTH_SUFFIX) or Path(name).name != name:
        return None
    if (SCENARIO_DIR / f"{name}.yaml").is_file():
        return None
    base = name[: -len(TRUTH_SUFFIX)]
    return base if base and (SCENARIO_DIR / f"{base}.yaml").is_file() else None


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load and validate a shipped scenario by name, or any scenario YAML by path; the name
    ``<X>_truth`` of no shipped file is shipped scenario X's `truth_twin`.

    Raises:
        ConfigError: no such scenario, or the file is invalid (the message names the file, the
            key, the bad value and what would be valid).
    """
    path = Path(name_or_path)
    base = truth_twin_base(str(name_or_path)) if path.suffix not in (".yaml", ".yml") else None
    if base is not None:
        return truth_twin(load_scenario(base))
    if path.suffix not in (".yaml", ".yml"):
        path = SCENARIO_DIR / f"{name_or_path}.yaml"
        if path.parent != SCENARIO_DIR or not is_file(path):  # a name, never a path
            valid = ", ".join(list_scenarios()) or "none"
            raise ConfigError(f"unknown scenario {str(name_or_path)!r}; valid: {valid}")
        _check_file_name(path, "a scenario under its folder is used by its file name")
    if not is_file(path):
        raise ConfigError(f"{path}: no such scenario file")
    data, _ = read_mapping(path, "scenario keys")
    if "name" not in data:
        _check_file_name(path, "a file without a 'name' key is named after it")
        data["name"] = path.stem
    scenario = _checked(_build(Scenario, data, source=str(path), prefix=""), str(path))
    return scenario


def _check_file_name(path: Path, why: str) -> None:
    """``ConfigError`` unless the file's stem is a valid scenario name (``why`` says why it
    must be)."""
    if IDENTIFIER.fullmatch(path.stem) is None:
        raise ConfigError(
            f"{path}: the file name {path.stem!r} is not a valid scenario name ({why}); "
            f"expected {IDENTIFIER_TEXT}"
        )


def _checked(scenario: Scenario, source: str) -> Scenario:
    """``scenario``, or ``ConfigError`` naming the keys if a rule that ties keys together is
    broken:

    * the hold is not shorter than the episode limit (no capture could complete);
    * the episode has more than `MAX_EPISODE_STEPS` control steps of the shortest real
      period (each is drawn at reset);
    * ``camera.look_at`` is within `MIN_LOOK_DISTANCE` of ``camera.position`` or straight
      above or below it (no view direction, or no camera z-axis);
    * ``target.initial_offset``'s low end is not above sqrt(3) ``capture_tolerance``: the target
      starts ``d`` from the home end-effector in a uniformly drawn direction ``u``, inside the
      eq. 20 box when ``d max|u_i| < epsilon``, and ``max|u_i| >= 1/sqrt(3)`` (equal on the
      box's diagonals), so a low end above sqrt(3) epsilon keeps every start outside it;
    * an evasive target would change its acceleration more than
      `MAX_JINKS` times in an episode;
    * the training seeds overlap the evaluation or validation seeds (the evaluation and
      validation ranges are adjacent by construction).
    """
    hold, limit = scenario.capture.hold, scenario.control.episode_limit
    if hold >= limit:
        raise ConfigError(
            f"{source}: key 'capture.hold': {hold!r} is not valid; expected a number >= 0 and "
            f"less than control.episode_limit ({limit!r} s), or no capture could complete"
        )
    control = scenario.control
    shortest = control.period * (1.0 - control.period_jitter)
    steps = control.episode_limit / shortest
    if steps > MAX_EPISODE_STEPS:
        jitter = f" (1 - {control.period_jitter!r} jitter)" if control.period_jitter else ""
        raise ConfigError(
            f"{source}: keys 'control.episode_limit' and 'control.period': "
            f"{control.episode_limit!r} s in steps of {control.period!r} s{jitter} is "
            f"{steps:.4g} steps, not valid; expected at most {MAX_EPISODE_STEPS} steps per episode"
        )
    _check_view(scenario.camera, source)
    low, epsilon = scenario.target.initial_offset[0], scenario.capture_tolerance
    if not low > math.sqrt(3.0) * epsilon:
        raise ConfigError(
            f"{source}: keys 'target.initial_offset' and 'capture_tolerance': a start "
            f"{low!r} m from the home end-effector can lie inside the capture box of "
            f"{epsilon!r} m (eq. 20, each component), captured at t = 0; expected "
            f"target.initial_offset's low above sqrt(3) x capture_tolerance "
            f"({math.sqrt(3.0) * epsilon:.4g} m)"
        )
    target = scenario.target
    if target.motion == "evasive" and limit / target.jink_interval[0] > MAX_JINKS:
        raise ConfigError(
            f"{source}: keys 'target.jink_interval' and 'control.episode_limit': "
            f"{limit!r} s in jinks of {target.jink_interval[0]!r} s is "
            f"{limit / target.jink_interval[0]:.4g} jinks, not valid; expected at most "
            f"{MAX_JINKS} in an episode"
        )
    train = scenario.training_seeds
    held_out = range(scenario.seeds.evaluation_start, scenario.validation_seeds.stop)
    if train.start < held_out.stop and held_out.start < train.stop:
        raise ConfigError(
            f"{source}: key 'seeds': the training seeds {train.start}-{train.stop - 1} overlap the "
            f"evaluation and validation seeds {held_out.start}-{held_out.stop - 1}; move "
            "seeds.training_start or seeds.evaluation_start so that the ranges are disjoint"
        )
    return scenario


def _check_view(camera: CameraConfig, source: str) -> None:
    """``ConfigError`` unless ``camera.look_at`` gives a view direction with a camera z-axis."""
    view = [b - a for a, b in zip(camera.position, camera.look_at)]
    distance = math.hypot(*view)
    if distance < MIN_LOOK_DISTANCE:
        raise ConfigError(
            f"{source}: keys 'camera.look_at' and 'camera.position': {list(camera.look_at)!r} "
            f"is {distance:.3g} m from {list(camera.position)!r}, not valid; expected a point at "
            f"least {MIN_LOOK_DISTANCE:g} m away (the camera looks from position to look_at)"
        )
    if math.hypot(view[0], view[1]) / distance < math.sin(MIN_VIEW_TILT):
        raise ConfigError(
            f"{source}: keys 'camera.look_at' and 'camera.position': {list(camera.look_at)!r} "
            f"is straight {'above' if view[2] > 0 else 'below'} {list(camera.position)!r}, not "
            "valid; expected a view direction that is not vertical (the camera's z-axis is the "
            "global z made perpendicular to it)"
        )


def _schema(cls: type) -> dict[str, Any]:
    """The validation schema of a config dataclass: a `Rule` per
    field (from its type and its ``bounds``/``choices`` metadata), a nested schema per section."""
    hints = typing.get_type_hints(cls)
    schema: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        kind, meta = hints[f.name], f.metadata
        if isinstance(kind, type) and dataclasses.is_dataclass(kind):
            schema[f.name] = _schema(kind)
        elif typing.get_origin(kind) is tuple:
            items = typing.get_args(kind)
            low, high, inclusive = meta.get("bounds") or (-math.inf, math.inf, True)
            schema[f.name] = Rule(
                "numbers", low, high, inclusive, length=len(items), item=items[0].__name__
            )
        elif typing.get_origin(kind) in (typing.Union, types.UnionType):  # a number or null
            low, high, inclusive = meta.get("bounds") or (-math.inf, math.inf, True)
            schema[f.name] = Rule("optional_float", low, high, inclusive)
        elif kind is str:
            choices = meta.get("choices")
            plain = Rule("identifier") if meta.get("identifier") else Rule("string")
            schema[f.name] = Rule("choice", choices=choices) if choices else plain
        else:
            low, high, inclusive = meta.get("bounds") or (-math.inf, math.inf, True)
            schema[f.name] = Rule(kind.__name__, low, high, inclusive)
    return schema


def _build(cls: type, data: dict[str, Any], source: str, prefix: str) -> Any:
    """Validate a mapping against dataclass ``cls`` (`capture_bench.validation.check_mapping`
    on `_schema`) and build it, sections recursively."""
    return _construct(cls, check_mapping(data, _schema(cls), source, prefix=prefix))


def _construct(cls: type, values: dict[str, Any]) -> Any:
    hints = typing.get_type_hints(cls)
    return cls(
        **{
            name: _construct(hints[name], value) if isinstance(value, dict) else value
            for name, value in values.items()
        }
    )
