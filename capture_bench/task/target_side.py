"""One producer of an episode's target side, live or recorded.

An episode's target side is everything on the target's half of every step: the true state
(trajectory, paper section 4), the camera's frame (eq. 2), the estimate in the global frame
(photogrammetry, EKF eqs. 3-7, 11-12), its errors and NEES, and reachability. None of it depends
on the agent's actions: after ``reset(seed=s)`` it is a function of the scenario, s and the step
index (the control periods, the trajectory, the camera's noise and drop-outs all come from the
seeded generator, in an order no action changes).

`TargetSide` holds it as one `RecordedEpisode` filled live: step k's row is computed when the
step asks for it (`TargetSide.through`), drawing the camera's noise from the episode's generator
then, step by step, as a plain gymnasium env would (a row of
`capture_bench.engine.sides.LiveSides`). Recorded ahead, the same rows come from
`capture_bench.task.recording.record_episodes`, bit for bit (the same draws in the same order, an
estimator row's numbers whatever the batch).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from capture_bench.sensing.camera import Camera, CameraEpisode, CameraModel, Frame
from capture_bench.sensing.detector import Detections
from capture_bench.sensing.estimator import TargetEstimator
from capture_bench.sensing.rendered_sensor import SceneEpisode
from capture_bench.sim import kinematics
from capture_bench.sim.target_motion import TargetTrajectory
from capture_bench.task.episode import EpisodePlan
from capture_bench.task.recording import RecordedEpisode, estimate_errors
from capture_bench.task.scenarios import Scenario

FloatArray = NDArray[np.float64]
ArmAt = Callable[[float], FloatArray]  # t, s -> the arm's joint angles then, rad, (3,)


class SceneCamera(Protocol):
    """A camera whose frame depends on the whole scene, the arm included (the rendered camera,
    `capture_bench.sensing.scene_camera.RenderedSceneCamera`): what a live
    `TargetSide` asks instead of `Camera.capture` of the feature points."""

    model: CameraModel

    def reset(
        self, rng: np.random.Generator, target_only: dict[int, Detections] | None = None
    ) -> SceneEpisode:
        """A new episode's state (its draws from ``rng`` come right after the plan's), reading
        and keeping the frames of the target alone in ``target_only`` (None: none kept)."""
        ...

    def capture_scene(
        self,
        state: SceneEpisode,
        k: int,
        time: float,
        trajectory: TargetTrajectory,
        arm_at: ArmAt,
        rng: np.random.Generator,
    ) -> Frame | None:
        """Frame k of the episode ``state`` (taken at ``time``, s), the target on ``trajectory``
        and the arm at ``arm_at(t)``; the frame delivered now, as `Camera.capture` returns
        it."""
        ...


class _Sensors(NamedTuple):
    """What a live side computes its rows with: the camera and its episode state, the
    estimator (one row), the feature points (target frame, m, (N, 3)) and the episode's
    generator."""

    camera: Camera | SceneCamera
    episode: CameraEpisode | SceneEpisode
    estimator: TargetEstimator
    features: FloatArray
    rng: np.random.Generator


class TargetSide:
    """One episode's target side as a `RecordedEpisode`, its rows filled up to
    `filled` (every row once complete).

    Build it with `live` (or `draw`); read row k of ``episode`` after `through` (k).
    """

    def __init__(
        self, episode: RecordedEpisode, filled: int, sensors: _Sensors | None = None
    ) -> None:
        self.episode = episode
        self.filled = filled  # rows 0 .. filled - 1 hold values
        self._sensors = sensors
        #: The arm's joint angles at a time of the current step (a scene camera's frame shows
        #: the arm): set by the env before `through` asks for the step's row.
        self.arm_at: ArmAt | None = None

    @classmethod
    def draw(
        cls,
        scenario: Scenario,
        camera: Camera | SceneCamera,
        estimator: TargetEstimator,
        features: FloatArray,
        rng: np.random.Generator,
        target_only: dict[int, Detections] | None = None,
    ) -> TargetSide:
        """The next episode of ``rng``: its plan drawn (`EpisodePlan.draw`, a winnable
        one), then `live` on it with the same generator."""
        plan = EpisodePlan.draw(scenario, camera.model, features, rng)
        return cls.live(plan, camera, estimator, features, rng, target_only)

    @classmethod
    def live(
        cls,
        plan: EpisodePlan,
        camera: Camera | SceneCamera,
        estimator: TargetEstimator,
        features: FloatArray,
        rng: np.random.Generator,
        target_only: dict[int, Detections] | None = None,
    ) -> TargetSide:
        """The episode of ``plan`` with its true states and reachability at every step time
        (`TargetTrajectory.states`, what the step-by-step `TargetTrajectory.state` gives, bit for
        bit) and nothing of the camera's side computed yet: a new episode of the camera (its
        true camera drawn from ``rng`` where it has a calibration error, `Camera.reset`; a
        scene camera's reading and keeping the target-only frames in ``target_only``, see
        `SceneCamera.reset`), the estimator reset, and each row, when asked for, drawing its
        frame's noise from ``rng``."""
        time, dt = plan.step_times()
        n, m = time.size, features.shape[0]
        position, velocity, rotation, _ = plan.trajectory.states(time)
        nan3 = np.full((n, 3), np.nan)
        episode = RecordedEpisode(
            plan=plan,
            time=time,
            dt=dt,
            position=position,
            velocity=velocity,
            rotation=rotation,
            images=np.full((n, m, 2), np.nan),
            visible=np.zeros(n, dtype=bool),
            estimate_position=nan3.copy(),
            estimate_velocity=nan3,
            estimate_valid=np.zeros(n, dtype=bool),
            estimate_covariance=np.full((n, 6, 6), np.nan),
            estimator_status=np.zeros(n, dtype=np.int8),
            reachable=kinematics.reachable(position),
            position_error=np.full(n, np.nan),
            velocity_error=np.full(n, np.nan),
            nees=np.full(n, np.nan),
            bound=None,
        )
        if isinstance(camera, Camera):  # its lens, if any, drawn as record_truth draws it
            state = camera.reset(None if plan.scenario.estimator.source == "truth" else rng)
        else:
            state = camera.reset(rng, target_only)
        estimator.reset()
        return cls(episode, 0, _Sensors(camera, state, estimator, features, rng))

    @property
    def camera_episode(self) -> CameraEpisode | SceneEpisode | None:
        """A live side's camera state (its latest capture's flags and, for a scene camera,
        detections); None for a side recorded or replayed."""
        return None if self._sensors is None else self._sensors.episode

    @property
    def complete(self) -> bool:
        """Whether every row, to the time limit, is filled."""
        return self.filled == self.episode.time.size

    def through(self, k: int) -> RecordedEpisode:
        """The episode with rows 0..k filled (a live side computes the missing rows now, in
        order), ``IndexError`` past the time limit's step."""
        while self.filled <= k:
            self._fill_next()
        return self.episode

    def _fill_next(self) -> None:
        """Row ``filled``: the camera's frame of the true state at its time (none with the truth
        source, whose env never calls the camera), the estimator's update, its errors."""
        if self._sensors is None or self.complete:
            raise IndexError(f"step {self.filled} is past the episode's time limit")
        camera, state, estimator, features, rng = self._sensors
        ep, k = self.episode, self.filled
        time = float(ep.time[k])
        x_t, v_t, rotation = ep.position[k], ep.velocity[k], ep.rotation[k]
        if ep.plan.scenario.estimator.source == "truth":
            frame = None
        elif isinstance(camera, Camera):
            assert isinstance(state, CameraEpisode)
            frame = camera.capture(state, x_t + features @ rotation.T, rng)
        else:
            if self.arm_at is None:
                raise RuntimeError("a scene camera's row needs the arm: set arm_at first")
            assert isinstance(state, SceneEpisode)
            frame = camera.capture_scene(state, k, time, ep.plan.trajectory, self.arm_at, rng)
        if frame is not None:
            ep.images[k] = frame.image_points
        ep.visible[k] = state.last_visible
        self._estimate_row(k, estimator, x_t, v_t)
        self.filled = k + 1

    def _estimate_row(
        self, k: int, estimator: TargetEstimator, x_t: FloatArray, v_t: FloatArray
    ) -> None:
        """Row k's estimate (the one-row estimator's update with the frame delivered then, NaN
        where none) and its errors."""
        ep = self.episode
        truth = (x_t[None], v_t[None])
        out = estimator.update(ep.images[k : k + 1], ep.dt[k : k + 1], None, truth)
        ep.estimate_valid[k] = out.valid[0]
        ep.estimate_position[k], ep.estimate_velocity[k] = out.position[0], out.velocity[0]
        ep.estimate_covariance[k] = out.covariance[0]
        ep.estimator_status[k] = out.status[0]
        errors = estimate_errors(out.position, out.velocity, out.covariance, out.valid, *truth)
        ep.position_error[k], ep.velocity_error[k], ep.nees[k] = (e[0] for e in errors)
