"""The task an env of a scenario plays, whatever the number of episodes it steps.

`CaptureTask`: the resolved scenario (`resolve_scenario`), what it publishes for agents
(`capture_bench.task.episode.describe_task`), the step rule (`StepRule`), the camera and the
target's feature points (`scenario_camera`), and the spaces of one episode. Each env owns one
(``env.task``, composition, as panda-gym's ``RobotTaskEnv`` owns its task;
`capture_bench.envs.core.TaskAccess` gives both envs the same public names for it).
`check_actions` is the one rule for an action's validity.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from capture_bench.sensing.camera import Camera
from capture_bench.sensing.rendered_sensor import RenderSettings
from capture_bench.sensing.sources import ENV_OBSERVATIONS, PIXELS
from capture_bench.sensing.workspace_image import (
    PixelOptions,
    WorkspaceImager,
    check_image_size,
)
from capture_bench.sim.target_motion import FEATURE_POINTS
from capture_bench.task.episode import describe_task, period_count
from capture_bench.task.observation import (
    encode_state,
    observation_space,
    pixel_observation_space,
)
from capture_bench.task.scenarios import Scenario, load_scenario
from capture_bench.task.step_rule import ArmState, StepRule
from capture_bench.validation import ConfigError

FloatArray = NDArray[np.float64]


def resolve_scenario(
    scenario: str | Path | Scenario, observation_source: str | None = None
) -> Scenario:
    """A shipped name, a YAML path or a ``Scenario``, with its estimator source replaced if
    ``observation_source`` is an estimator source (checked; ``"pixels"`` keeps the scenario's
    estimator, which then runs for ``info`` only)."""
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    if observation_source is not None and observation_source != PIXELS:
        sc = sc.replace(estimator={"source": observation_source})
    return sc


def scenario_camera(scenario: Scenario) -> tuple[Camera, FloatArray]:
    """The scenario's camera (model, noise, drop-out, latency, lens and calibration error) and
    the target's feature points (target frame, m, (N, 3))."""
    cam = scenario.camera
    spread = cam.calibration_spread()
    camera = Camera(cam.model(), cam.noise_px, cam.dropout, cam.latency_frames, spread)
    return camera, FEATURE_POINTS[scenario.target.feature_points]


def check_actions(actions: Any, shape: tuple[int, ...], name: str) -> FloatArray:
    """``actions`` as a float64 array of ``shape``, or ``ValueError`` naming what is wrong.

    Accepts any array-like of real numbers (bool, int or float dtype; lists and tuples too);
    refuses other types (strings, complex, objects), another shape, and NaN or infinite entries
    (the message gives the index of the first). Values outside [-1, 1] pass: the envs clip them.
    """
    try:
        raw = np.asarray(actions)
    except (TypeError, ValueError) as exc:  # ragged nested lists
        raise ValueError(f"{name} must be an array of shape {shape} of numbers; {exc}") from None
    if raw.dtype.kind not in "biuf":
        raise ValueError(
            f"{name} must be an array of shape {shape} of real numbers; got dtype {raw.dtype} "
            f"({actions!r})"
        )
    if raw.shape != shape:
        raise ValueError(f"{name} must have shape {shape}; got shape {raw.shape} ({actions!r})")
    a = raw.astype(np.float64)
    bad = ~np.isfinite(a)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        entry = f"{name}[{', '.join(map(str, index))}]"
        raise ValueError(
            f"{entry} is {a[index]}; every entry must be a finite number "
            "(values outside [-1, 1] are clipped)"
        )
    return a


#: An observation: the estimate's vector, (16,) (or (N, 16) for N episodes), or with pixels
#: ``{"image": (3, H, W) uint8, "state": (7,) float32}`` (each with a leading N).
Observation = NDArray[np.float32] | dict[str, NDArray]


def pixel_options(
    options: dict[str, Any], pixels: bool, observation_source: str | None
) -> PixelOptions:
    """``options`` (name -> value or None) checked (`PixelOptions.check`); ``ConfigError``
    where one is given without pixels."""
    given = [name for name, value in options.items() if value is not None]
    if given and not pixels:
        raise ConfigError(
            f"{given[0]}={options[given[0]]!r} applies only with observation_source="
            f'"pixels" (given observation_source={observation_source!r}); drop it or pass '
            'observation_source="pixels"'
        )
    try:
        return PixelOptions.check(**options)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


class CaptureTask:
    """The task of ``scenario`` as an env plays it, for any number of episodes.

    Args:
        scenario: a shipped name, a YAML path or a ``Scenario``.
        observation_source: an estimator source, ``"ekf"``, ``"photogrammetry"`` or ``"truth"``
            (default: the scenario's), whose estimate the agent observes; or ``"pixels"``: the
            agent observes the camera's image and the arm's state
            (`pixel_observation_space`) and the scenario's
            estimator runs for ``info`` only.
        reward: one of `capture_bench.task.rewards.REWARD_MODES` (checked).
        image_size: with ``"pixels"``, the image's (width, height), pixels (checked:
            `check_image_size`); None (default):
            `IMAGE_SIZE`. Given with any other
            source, ``ConfigError``: it sizes nothing there.
        frame_stack: with ``"pixels"``, the frame stack (`PixelOptions`; None: its
            default); checked, one-line ``ValueError``; given (not None) with any other
            source, ``ConfigError``; the same for the four below.
        ee_crop: the end-effector crop's side, pixels (`PixelOptions`).
        ee_crop_scale: sensor pixels per crop pixel (`PixelOptions`).
        image_supersample: samples per image pixel, a side (`PixelOptions`).
        ee_crop_supersample: the same for the crop (`PixelOptions`).

    Attributes:
        scenario: the resolved ``Scenario``.
        description: what agents may know (`
            TaskDescription`).
        rule: the step rule (`StepRule`).
        reward_mode: ``reward``.
        camera, features: the scenario's camera and the target's feature points (target frame,
            m, (N, 3)).
        single_action_space: ``Box(-1, 1, (3,), float32)``; single_observation_space: the
            observation of one episode (`
            observation_space`, or the pixel ``Dict``).
        pixels: whether the agent observes pixels; image_size: (width, height), pixels;
        pixel_options: `PixelOptions`.
        steps: the most rows (reset included) an episode has.
    """

    def __init__(
        self,
        scenario: str | Path | Scenario,
        *,
        observation_source: str | None = None,
        reward: str = "dense",
        image_size: tuple[int, int] | None = None,
        frame_stack: int | None = None,
        ee_crop: int | None = None,
        ee_crop_scale: int | None = None,
        image_supersample: int | None = None,
        ee_crop_supersample: int | None = None,
    ) -> None:
        if observation_source is not None and observation_source not in ENV_OBSERVATIONS:
            raise ConfigError(
                f"observation_source {observation_source!r} is not valid; expected one of "
                f"{', '.join(ENV_OBSERVATIONS)} (or None: the scenario's estimator)"
            )
        self.scenario = resolve_scenario(scenario, observation_source)
        self.description = describe_task(self.scenario)
        self.rule = StepRule(self.scenario, self.description, reward)  # checks ``reward``
        self.reward_mode = reward
        self.camera: Camera
        self.camera, self.features = scenario_camera(self.scenario)
        self.pixels = observation_source == PIXELS
        if image_size is not None and not self.pixels:
            raise ConfigError(
                f'image_size={image_size!r} applies only with observation_source="pixels" (it '
                f"sizes the pixel observation; given observation_source={observation_source!r}); "
                'drop image_size or pass observation_source="pixels"'
            )
        self.image_size = check_image_size(image_size, self.camera.model)
        options = {
            "frame_stack": frame_stack,
            "ee_crop": ee_crop,
            "ee_crop_scale": ee_crop_scale,
            "image_supersample": image_supersample,
            "ee_crop_supersample": ee_crop_supersample,
        }
        self.pixel_options = pixel_options(options, self.pixels, observation_source)
        ee_side = self.pixel_options.ee_crop * self.pixel_options.ee_crop_scale
        if ee_side > min(self.camera.model.resolution):
            raise ConfigError(
                f"ee_crop x ee_crop_scale = {ee_side} sensor pixels is more than the sensor's "
                f"shorter side, {min(self.camera.model.resolution)}; make either smaller"
            )
        self.single_action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self.single_observation_space: spaces.Space = (
            pixel_observation_space(
                self.image_size, self.pixel_options.frame_stack, self.pixel_options.ee_crop
            )
            if self.pixels
            else observation_space()
        )

    @property
    def steps(self) -> int:
        """The most rows an episode has: reset and one per control period up to the time
        limit."""
        return period_count(self.scenario.control) + 1

    def imager(self) -> WorkspaceImager:
        """A renderer of this task's pixel observation (it opens a pybullet world: the caller
        closes it), lit as the scenario's camera keys say."""
        cam = self.scenario.camera
        x, y, z = (float(v) for v in cam.light_direction)
        settings = RenderSettings(
            light_direction=(x, y, z) if any((x, y, z)) else None,
            light_intensity=cam.light_intensity,
        )
        model = self.camera.model
        return WorkspaceImager(
            model, self.features, self.image_size, settings.lighting(), options=self.pixel_options
        )

    def pixel_observation(
        self,
        imager: WorkspaceImager,
        state: ArmState,
        rows: Any,
        position: FloatArray,
        rotation: FloatArray,
        dt: FloatArray,
    ) -> dict[str, NDArray]:
        """The pixel observation of episodes ``rows`` of ``state`` (M of them): the image of
        their arm and of the target at ``position`` (M, 3) and ``rotation`` (M, 3, 3), and their
        state with the last real periods ``dt`` (M,), s: ``image`` (M, 3, H, W), ``state``
        (M, 7); with the end-effector crop, ``ee_image`` (M, 3, n, n) too. One frame: the frame
        stack is the engine's."""
        theta, x_e = state.theta[rows], state.x_e[rows]
        views: dict[str, NDArray] = imager.render_views(theta, position, rotation, x_e)
        views["state"] = encode_state(theta, x_e, dt, self.description.control_period)
        return views

    def increments(self, actions: FloatArray) -> FloatArray:
        """The joint increments M actions (M, 3) request, rad: each entry clipped to [-1, 1],
        then ``a_i * theta_dot_max_i * t_s``."""
        clipped = np.minimum(np.maximum(actions, -1.0), 1.0)
        return self.description.action_to_increment(clipped)
