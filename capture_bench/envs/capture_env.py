"""``CaptureEnv``: the gymnasium environment. The only module that knows every stage."""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from capture_bench.sensing.camera import Camera, CameraModel
from capture_bench.sensing.estimator import (
    TargetEstimate,
    TargetEstimator,
    normalised_error_squared,
)
from capture_bench.sim import kinematics
from capture_bench.sim.target_motion import FEATURE_POINTS, TargetTrajectory
from capture_bench.sim.world import World
from capture_bench.task.capture import (
    ARC_RESOLUTION,
    arc_sag_bound,
    closest_approach,
    first_entry_along_arc,
    first_entry_fraction,
    segment_length,
)
from capture_bench.task.episode import TIME_SLACK, EpisodePlan, episode_bounds, time_limit
from capture_bench.task.observation import TaskDescription, encode_observation, observation_space
from capture_bench.task.physical_limit import PhysicalLimit
from capture_bench.task.rewards import REWARD_MODES, reward_terms
from capture_bench.task.scenarios import Scenario, load_scenario

FAILURES = ("timeout", "collision", "target_lost", "unreachable")
# Physical-limit bounds already computed in this process, by (scenario, seed): ``reset(seed=s)``
# draws the target's trajectory from the scenario and s alone, before anything an agent does, so
# every agent evaluated on the same seed has the same bound (it costs ~8 ms per episode).
_LIMIT_CACHE: dict[tuple[Scenario, int], PhysicalLimit] = {}
_LIMIT_CACHE_SIZE = 65_536


def check_actions(actions: Any, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
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


class TargetStep(NamedTuple):
    """The target's side of one control step: its true state, what the camera and estimator made
    of it, and what the env derives from those alone.

    Nothing here depends on the agent's actions: after ``reset(seed=s)`` the sequence of these is
    a function of the scenario, s and the step index (the control period, the trajectory, the
    camera's noise and drop-outs all come from the seeded generator, in an order no action
    changes). ``CaptureEnv(reuse_target_side=True)`` relies on this.
    """

    time: float  # s since reset
    dt: float  # the control period that ended here, s
    position: NDArray[np.float64]  # X_T, global, m
    velocity: NDArray[np.float64]  # X_T-dot, global, m/s
    rotation: NDArray[np.float64]  # R_gt
    estimate: TargetEstimate
    visible: bool  # every marker in view at this capture
    reachable: bool  # X_T inside the arm's joint-limited reach
    position_error: float  # |X_T-hat - X_T|, m (NaN without a valid estimate)
    velocity_error: float  # m/s
    nees: float  # NEES of (position, velocity) (NaN without a covariance)


# Target sides of whole episodes already recorded in this process (``reuse_target_side=True``), by
# (scenario, seed), least recently used first. An evaluation runs every agent on a few seeds at a
# time in one worker, so a few entries suffice; each holds one episode's steps (~200).
# (trajectory, control periods, target side of every step, np_random's state after recording)
_Recorded = tuple[TargetTrajectory, NDArray[np.float64], list[TargetStep], Mapping[str, Any]]
_EPISODE_CACHE: OrderedDict[tuple[Scenario, int], _Recorded] = OrderedDict()
_EPISODE_CACHE_SIZE = 16  # ~1 MB each


class CaptureEnv(gym.Env):
    """Capture a drifting or tumbling target with the 3-joint arm of Dong & Zhu (2016).

    ## Description
    The arm (paper Table 1) starts at home, Θ = (0, 90°, 0). A non-cooperative target moves along
    a trajectory drawn from the scenario (drift, circular, tumbling, evasive). The agent never
    sees the target: a fixed camera (eq. 2) images four feature points, and photogrammetry
    initialises an extended Kalman filter (eqs. 3–7) whose estimate, in the global frame
    (eqs. 11–12), is observed. Capture is eq. 20 on the *true* target position, tested over the
    whole step.

    ## Action Space
    ``Box(-1, 1, (3,), float32)``: ``ΔΘ_i = a_i · θ̇_max,i · t_s`` rad, θ̇_max = (10.304, 0.412,
    0.412) rad/s. The world clips every increment to ``θ̇_max,i · dt`` of the real period and to the
    joint limits, whatever the agent asks. Actions outside [-1, 1] (however large) are clipped.
    An action that is not a real number array of shape (3,) (a list or tuple of numbers is fine,
    any int or float dtype), or that holds a NaN or an infinity, raises ``ValueError`` naming the
    bad entry, and the step is not taken. Non-finite actions are refused rather than zeroed or
    clipped: a NaN from a policy means a diverged network, and a benchmark that quietly turned
    it into "hold still" would score the broken policy; Gymnasium's ``Box.contains`` refuses
    them too. :class:`~capture_bench.envs.vector_env.CaptureVectorEnv` applies the same rule
    (:func:`check_actions`) to its (num_envs, 3) actions.

    ## Observation Space
    ``Box(-10, 10, (16,), float32)``, each entry scaled to order one
    (``capture_bench.task.observation.decode_observation`` undoes it):

    | index | quantity (global frame)                       | unit | scale   |
    |-------|-----------------------------------------------|------|---------|
    | 0–2   | estimated capture point X̂_T                   | m    | 1 m     |
    | 3–5   | estimated target velocity                     | m/s  | 0.1 m/s |
    | 6–8   | end-effector position X_E                     | m    | 1 m     |
    | 9–11  | joint angles Θ                                | rad  | π       |
    | 12–14 | predicted relative vector X̂_T + Ẋ̂_T t_s − X_E | m    | 0.5 m   |
    | 15    | last real control period dt                   | s    | t_s     |

    While the estimator has no estimate yet (e.g. during camera latency), the target entries
    repeat the end-effector position with zero velocity.

    ## Rewards
    ``reward="dense"`` (default): ``reward_progress = 10 (d_prev − d)`` (d: true distance, m),
    ``reward_time = −0.01`` per step, ``reward_capture = +5`` on capture, ``reward_failure = −5`` on
    collision, target_lost or unreachable. ``reward="sparse"``: 1 on capture, else 0. Each term is
    in ``info``.

    ## Starting State
    Home pose. The capture point starts ``target.initial_offset`` m from the home end-effector in a
    uniformly drawn direction, redrawn until it is inside the joint-limited workspace and above the
    floor, and its four markers are inside the central 90% of the image at t = 0, 1, 2 and 3 s.
    Orientation, velocity, tumble and path are drawn from the scenario's ranges with
    ``self.np_random``, then the real control period of every step (``period_jitter``).

    ## Episode End
    Terminates on capture (``info["is_success"]``) or a failure: ``collision`` (arm with floor,
    base or itself), ``target_lost`` (no usable frame for ``lost_after`` s: out of view, behind the
    lens, dropped, or the estimator diverged; never with the ``truth`` source), ``unreachable``
    (the capture point outside the arm's joint-limited reach for ``lost_after`` s). Truncates at
    ``control.episode_limit`` s of *simulated* time with failure ``timeout``. The env truncates
    itself, not a ``TimeLimit`` wrapper, because the limit is in seconds and the control period
    varies in some scenarios.

    ## Info
    Every step: ``is_success``, ``failure`` (None or one of ``FAILURES``), ``capture_time`` (s),
    ``capture_time_estimated`` (s: first time eq. 20 held on the *estimated* position, as the
    paper's hardware could only judge), ``time``, ``dt``, ``distance``, ``relative_speed``,
    ``estimate_position_error``, ``estimate_velocity_error``, ``estimate_nees``, ``saturated``,
    ``clipped``, ``path_length``, ``target_visible``, ``estimator_status``, ``reward_*``. At the
    end:
    ``physical_limit_time`` (s; ``inf`` when the target cannot be reached before the time limit,
    or leaves the arm's reach for longer than ``lost_after`` before it can be).

    ## Arguments
    ``scenario``: a shipped name (``capture_bench.task.scenarios.list_scenarios()``), a YAML path
    or a ``Scenario``. ``observation_source``: ``"ekf"``, ``"photogrammetry"`` or ``"truth"``
    (default: the scenario's). ``reward``: ``"dense"`` or ``"sparse"``. ``render_mode``:
    ``"rgb_array"`` or ``"human"``. ``reuse_target_side``: when True, ``reset(seed=s)`` records
    the target's side of the whole episode up to the time limit at once (trajectory, control
    periods, camera frames, estimates: see :class:`TargetStep`, none of which depends on the
    actions) and keeps it in this process by (scenario, s); a later ``reset(seed=s)`` replays it
    instead of computing it again. Every observation, reward and ``info`` is identical to a run
    without it; an evaluation that runs many agents on the same seeds saves the camera and
    estimator work of all but the first. An unseeded reset is recorded the same way but not kept.
    After any reset ``np_random`` stands where the recording left it (the time limit), so the
    episodes that follow a seeded reset are the same whatever the actions, though after the
    first they are not the ones a plain env gives (it advances ``np_random`` by the steps actually
    taken); :class:`~capture_bench.envs.vector_env.CaptureVectorEnv` gives exactly these episodes.
    Default False: each reset pays for the whole horizon.

    ## Version History
    * v0: initial release.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 20}

    def __init__(
        self,
        scenario: str | Path | Scenario = "paper",
        *,
        observation_source: str | None = None,
        reward: str = "dense",
        render_mode: str | None = None,
        reuse_target_side: bool = False,
    ) -> None:
        self.scenario = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        if observation_source is not None:
            self.scenario = self.scenario.replace(estimator={"source": observation_source})
        if reward not in REWARD_MODES:
            raise ValueError(f"reward must be one of {REWARD_MODES}, got {reward!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        self.reward_mode = reward
        self.render_mode = render_mode
        self.reuse_target_side = bool(reuse_target_side)
        sc = self.scenario
        self.description = TaskDescription(
            arm=kinematics.ArmSpec(),
            control_period=sc.control.period,
            capture_tolerance=np.full(3, sc.capture_tolerance),
        )
        self._tolerance_radius = float(np.linalg.norm(self.description.capture_tolerance))
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self.observation_space = observation_space()
        self._features = FEATURE_POINTS[sc.target.feature_points]
        cam = sc.camera
        self.camera_model = CameraModel.looking_at(
            cam.position,
            cam.look_at,
            focal_length=cam.focal_length,
            pixel_pitch=cam.pixel_pitch,
            resolution=cam.resolution,
        )
        self._camera = Camera(self.camera_model, cam.noise_px, cam.dropout, cam.latency_frames)
        self._estimator = TargetEstimator(
            self.camera_model, self._features, source=sc.estimator.source, **sc.estimator_settings()
        )
        self._world: World | None = None
        self._closed = False
        self._trajectory: TargetTrajectory | None = None
        self._limit: PhysicalLimit | None = None
        self._limit_key: tuple[Scenario, int] | None = None
        self._script: list[TargetStep] | None = None  # the recorded target side being replayed
        self._steps = 0  # steps since reset
        self._periods = np.empty(0)  # real control period of every step, s (drawn at reset)
        self._episode_over = True

    # -- privileged API (oracle and tests only) ------------------------------------------------
    def physical_limit(self) -> PhysicalLimit:
        """The episode's lower bound on capture time (computed once per episode, lazily)."""
        if self._trajectory is None:
            raise RuntimeError("call reset() before physical_limit()")
        if self._limit is None and self._limit_key is not None:
            self._limit = _LIMIT_CACHE.get(self._limit_key)
        if self._limit is None:
            (self._limit,) = episode_bounds([self._plan()], self.description)
            if self._limit_key is not None:
                if len(_LIMIT_CACHE) >= _LIMIT_CACHE_SIZE:
                    _LIMIT_CACHE.clear()
                if self._limit.theta is not None:
                    self._limit.theta.flags.writeable = False  # shared between episodes
                _LIMIT_CACHE[self._limit_key] = self._limit
        return self._limit

    def _plan(self) -> EpisodePlan:
        """This episode's trajectory and control periods, as reset drew them."""
        assert self._trajectory is not None
        return EpisodePlan(self.scenario, self._trajectory, self._periods)

    def true_target_position(self, t: float | NDArray) -> NDArray[np.float64]:
        """X_T(t), global, m (privileged)."""
        if self._trajectory is None:
            raise RuntimeError("call reset() before true_target_position()")
        return self._trajectory.position(t)

    @property
    def time(self) -> float:
        """Simulated time since reset, s."""
        return self._time

    @property
    def next_control_period(self) -> float:
        """The real period of the next step, s (privileged: the periods are drawn at reset)."""
        if self._trajectory is None:
            raise RuntimeError("call reset() before next_control_period")
        return float(self._periods[self._steps])

    @property
    def joint_angles(self) -> NDArray[np.float64]:
        """Current joint angles, rad, (3,)."""
        return self._theta.copy()

    # -- gymnasium API --------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        super().reset(seed=seed)
        sc = self.scenario
        self._closed = False
        if self._world is None:
            self._world = World(self._features, render_mode=self.render_mode)
        key = None if seed is None else (self.scenario, int(seed))
        self._script = None
        if self.reuse_target_side:
            self._trajectory, self._periods, self._script, rng_state = self._recorded_target_side(
                key
            )
            self.np_random.bit_generator.state = rng_state
        else:
            self._start_target_side()
        self._steps = 0
        self._limit = None
        self._limit_key = key
        self._theta = self.description.arm.home.copy()
        self._time = 0.0
        if self._script is None:
            target = self._advance_target(0.0, sc.control.period)
        else:
            target = self._script[0]
        self._target = target
        self._x_t, self._estimate = target.position, target.estimate
        self._x_e = kinematics.forward_kinematics_point(self._theta)
        self._world.reset(self._theta, self._x_t, target.rotation)
        self._since_frame = 0.0
        self._unreachable_for = 0.0
        self._path_length = 0.0
        self._capture_time_estimated: float | None = None
        self._traces: dict[str, list[NDArray]] = {
            "target": [self._x_t],
            "end_effector": [self._x_e],
        }
        self._episode_over = False
        obs = self._observation(sc.control.period)
        self._distance = segment_length(self._x_e, self._x_t)
        info = {"time": 0.0, "distance": self._distance}
        return obs, info

    def step(
        self, action: NDArray
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        if self._closed:
            raise RuntimeError("CaptureEnv.step() called after close(); the env is closed")
        if self._world is None or self._trajectory is None:
            raise RuntimeError("CaptureEnv.step() called before reset(); call env.reset() first")
        if self._episode_over:
            raise RuntimeError("the episode has ended; call env.reset() before step()")
        a = check_actions(action, (3,), "action")
        desc = self.description
        self._steps += 1
        if self._script is None:  # the target's side of the step (it draws from np_random)
            target = self._next_target(self._target, self._steps - 1)
        else:
            target = self._script[self._steps]
        dt = target.dt

        x_e0, x_t0, est0, d_prev = self._x_e, self._x_t, self._estimate, self._distance
        joint_step = self._world.apply_joint_increment(
            desc.action_to_increment(np.minimum(np.maximum(a, -1.0), 1.0)), dt
        )
        self._theta = joint_step.theta
        self._target = target
        self._time = target.time
        self._x_t = target.position
        self._world.set_target_pose(self._x_t, target.rotation)
        self._x_e = kinematics.forward_kinematics_point(self._theta)
        self._path_length += segment_length(x_e0, self._x_e)

        s = self._capture_fraction(joint_step, x_e0, x_t0, dt)
        captured = s is not None
        capture_time = self._time - dt + s * dt if s is not None else None

        self._estimate = est = target.estimate
        if self._capture_time_estimated is None and est0.valid and est.valid:
            s_est = first_entry_fraction(
                x_e0 - est0.position, self._x_e - est.position, desc.capture_tolerance
            )
            if s_est is not None:
                self._capture_time_estimated = self._time - dt + s_est * dt

        failure = None if captured else self._failure(dt)
        terminated = captured or failure is not None
        truncated = False
        if not terminated and self._time >= self._time_limit():
            truncated, failure = True, "timeout"
        self._episode_over = terminated or truncated

        self._distance = distance = segment_length(self._x_e, self._x_t)
        terms = reward_terms(self.reward_mode, d_prev, distance, captured, failure)
        info = self._info(dt, distance, x_e0, joint_step, captured, capture_time, failure)
        info.update(terms)
        if self._episode_over:
            info["physical_limit_time"] = self.physical_limit().time
        if self.render_mode is not None:
            self._traces["target"].append(self._x_t)
            self._traces["end_effector"].append(self._x_e)
        return self._observation(dt), float(sum(terms.values())), terminated, truncated, info

    def render(self) -> NDArray[np.uint8] | None:
        if self.render_mode is None or self._world is None:
            return None
        traces = {k: np.array(v) for k, v in self._traces.items()}
        image = self._world.render(traces=traces)
        return image if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        """Disconnect the pybullet world; safe twice. ``step()`` then raises; ``reset()`` opens a
        new world and the env can be used again."""
        self._closed = True
        if self._world is not None:
            self._world.close()
            self._world = None

    # -- stages ---------------------------------------------------------------------------------
    def _advance_target(self, time: float, dt: float) -> TargetStep:
        """The target's side of the step ending at ``time``: true state, camera frame (unless the
        source is truth) -> estimator -> estimate (global frame), and its errors."""
        assert self._trajectory is not None
        x_t, v_t, rotation = self._trajectory.state(time)
        if self.scenario.estimator.source == "truth":
            frame = None
        else:
            frame = self._camera.capture(x_t + self._features @ rotation.T, self.np_random)
        est = self._estimator.update(frame, dt, x_t, v_t)
        pos_err = vel_err = nees = math.nan
        if est.valid:
            pos_err = segment_length(est.position, x_t)
            vel_err = segment_length(est.velocity, v_t)
            if est.covariance is not None:
                e = np.concatenate([est.position - x_t, est.velocity - v_t])
                nees = normalised_error_squared(e, est.covariance)
        return TargetStep(
            time,
            dt,
            x_t,
            v_t,
            rotation,
            est,
            bool(self._camera.last_visible),
            kinematics.reachable(x_t),
            pos_err,
            vel_err,
            nees,
        )

    def _next_target(self, previous: TargetStep, index: int) -> TargetStep:
        """The target's side of step ``index`` (0-based), the one after ``previous``."""
        dt = float(self._periods[index])
        return self._advance_target(previous.time + dt, dt)

    def _time_limit(self) -> float:
        """The time at which ``step`` truncates, s (the episode limit, less the rounding slack)."""
        return time_limit(self.scenario.control)

    def _start_target_side(self) -> None:
        """A new trajectory and control periods from ``np_random``, and a camera and estimator
        that know nothing."""
        plan = EpisodePlan.draw(self.scenario, self.camera_model, self._features, self.np_random)
        self._trajectory, self._periods = plan.trajectory, plan.periods
        self._camera.reset()
        self._estimator.reset()

    def _recorded_target_side(self, key: tuple[Scenario, int] | None) -> _Recorded:
        """This seed's trajectory, control periods and the target's side of every step from reset
        to the time limit (``step`` truncates there), recorded now unless this process already
        has them (an unseeded reset, ``key`` None, is recorded and not kept). They are computed
        as live steps would compute them, in the same order of random draws."""
        recorded = None if key is None else _EPISODE_CACHE.get(key)
        if key is not None and recorded is not None:
            _EPISODE_CACHE.move_to_end(key)
            return recorded
        self._start_target_side()
        steps = [self._advance_target(0.0, self.scenario.control.period)]
        while steps[-1].time < self._time_limit():
            steps.append(self._next_target(steps[-1], len(steps) - 1))
        assert self._trajectory is not None
        state = self.np_random.bit_generator.state
        recorded = (self._trajectory, self._periods, steps, state)
        if key is None:
            return recorded
        _EPISODE_CACHE[key] = recorded
        if len(_EPISODE_CACHE) > _EPISODE_CACHE_SIZE:
            _EPISODE_CACHE.popitem(last=False)
        return recorded

    def _capture_fraction(self, joint_step, x_e0, x_t0, dt: float) -> float | None:
        """Fraction of this step at which eq. 20 first held on the true target, or None."""
        d0, d1 = x_e0 - x_t0, self._x_e - self._x_t
        tolerance = self.description.capture_tolerance
        sag = arc_sag_bound(joint_step.applied)
        if sag <= ARC_RESOLUTION:
            return first_entry_fraction(d0, d1, tolerance)
        if closest_approach(d0, d1) > self._tolerance_radius + sag:
            return None  # the arc stays within `sag` of the chord: no capture possible
        t0, traj = self._time - dt, self._trajectory
        assert traj is not None
        return first_entry_along_arc(
            joint_step.theta_before,
            joint_step.applied,
            lambda s: traj.position(t0 + s * dt),
            tolerance,
        )

    def _failure(self, dt: float) -> str | None:
        """The one failure reason of this step, if any (collision, unreachable, target_lost)."""
        assert self._world is not None
        if self._world.collision() is not None:
            return "collision"
        reach = self._target.reachable
        self._unreachable_for = 0.0 if reach else self._unreachable_for + dt
        if self._unreachable_for > self.scenario.lost_after + TIME_SLACK:
            return "unreachable"
        if self.scenario.estimator.source != "truth":
            usable = self._estimate.status == "ok"
            self._since_frame = 0.0 if usable else self._since_frame + dt
            if self._since_frame > self.scenario.lost_after + TIME_SLACK:
                return "target_lost"
        return None

    def _observation(self, dt: float) -> NDArray[np.float32]:
        est = self._estimate
        if est.valid:
            position, velocity = est.position, est.velocity
        else:
            position, velocity = self._x_e, np.zeros(3)
        return encode_observation(
            position, velocity, self._x_e, self._theta, dt, self.scenario.control.period
        )

    def _info(self, dt, distance, x_e0, joint_step, captured, capture_time, failure):
        target = self._target
        v_e = (self._x_e - x_e0) / dt
        return {
            "is_success": captured,
            "failure": failure,
            "capture_time": capture_time,
            "capture_time_estimated": self._capture_time_estimated,
            "time": self._time,
            "dt": dt,
            "distance": distance,
            "relative_speed": segment_length(v_e, target.velocity),
            "estimate_position_error": target.position_error,
            "estimate_velocity_error": target.velocity_error,
            "estimate_nees": target.nees,
            "saturated": joint_step.saturated,
            "clipped": joint_step.clipped,
            "path_length": self._path_length,
            "target_visible": target.visible,
            "estimator_status": self._estimate.status,
        }
