"""The task's rules for one control step, over N episodes at once (numpy): written once, for
``CaptureEnv`` (its N = 1 case) and ``CaptureVectorEnv``.

The model is Gymnasium's functional CartPole (``gymnasium/envs/phys2d/cartpole.py``), whose one
transition function serves both its single and its vector env. Here the envs do the simulation's
half of a step (the world's rate and joint limits, forward kinematics, the collision query) and
read the target's half from a :class:`~capture_bench.task.recording.RecordedEpisode`; then
:meth:`StepRule.step` applies the rules:

* capture (eq. 20, ``|X_E - X_T| < epsilon`` component-wise) on the *true* target, tested along
  the end-effector's arc over the whole step (:mod:`capture_bench.task.capture`); with a hold
  (``capture.hold`` s of the scenario) eq. 20 must hold without a break for that long, and the
  capture is when the hold completes (:func:`~capture_bench.task.capture.held_capture`; the
  stay in progress is carried in :class:`ArmState`);
* the same test (and hold) on the *estimated* target, the first time it completes
  (``capture_time_estimated``: what the paper's hardware could judge);
* the failure, in this order: ``collision``, ``unreachable``, ``target_lost`` (each only if the
  step did not capture), then ``timeout`` at the time limit (a truncation);
* the reward terms (:mod:`capture_bench.task.rewards`);
* the ``info`` entries (:data:`INFO_KEYS`, then the reward terms; :data:`END_INFO_KEYS` where an
  episode ended, filled by the env, which owns the bound);
* the observation (:mod:`capture_bench.task.observation`, eq. 13's predicted relative vector).

Adding an ``info`` key, a reward term, an observation entry or a failure reason is an edit here
(or in ``rewards.py`` / ``observation.py``); tests check both envs expose exactly these sets.

Why one file of ~530 lines: :meth:`StepRule.step` (N episodes, numpy) and its one-episode fast
path :meth:`StepRule.step_scalar` (the single env: numpy's per-call overhead would double a
replayed step's cost) are the same rules and must change together; side by side, a change to one
is seen next to the other, and ``tests/test_step_rule.py`` checks them equal.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.sensing.estimator import STATUSES
from capture_bench.sim import kinematics
from capture_bench.sim.target_motion import TargetTrajectory
from capture_bench.task.capture import (
    ARC_RESOLUTION,
    arc_sag_bound,
    arc_sag_bounds,
    closest_approach,
    closest_approaches,
    held_capture,
    inside_interval,
    inside_intervals,
    inside_intervals_along_arc,
    segment_length,
)
from capture_bench.task.episode import TIME_SLACK, time_limit
from capture_bench.task.observation import (
    TaskDescription,
    encode_observation,
    encode_observations,
)
from capture_bench.task.recording import RecordedEpisode
from capture_bench.task.rewards import (
    REWARD_MODES,
    REWARD_TERMS,
    UNPENALISED_FAILURES,
    reward_terms,
    total_reward,
)
from capture_bench.task.scenarios import Scenario

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
Rows = slice | NDArray[np.intp]  # which of the N episodes take part

#: Every failure reason an episode can end with (exactly one, if it does not capture).
FAILURES = ("timeout", "collision", "target_lost", "unreachable")
#: ``failure`` codes index this: 0 is no failure, 1 + FAILURES.index(reason) a reason.
FAILURE_NAMES = np.array((None, *FAILURES), dtype=object)
COLLISION, UNREACHABLE, TARGET_LOST, TIMEOUT = (
    1 + FAILURES.index(name) for name in ("collision", "unreachable", "target_lost", "timeout")
)
# by failure code: whether it earns the failure penalty (no failure and UNPENALISED_FAILURES not)
_PENALISED = np.array([False] + [name not in UNPENALISED_FAILURES for name in FAILURES])
_STATUS_OK = STATUSES.index("ok")
_STATUS_NAMES = np.array(STATUSES, dtype=object)

#: ``info`` of every step, in this order (the reward terms of the mode follow).
INFO_KEYS = (
    "is_success",  # the capture completed during the step (eq. 20 on the true target, held)
    "failure",  # None or one of FAILURES
    "capture_time",  # s, when the capture completed (None / NaN: no capture)
    "capture_time_estimated",  # s, the same test first completed on the estimate (None / NaN)
    "time",  # s since reset
    "dt",  # the step's real control period, s
    "distance",  # true ||X_E - X_T|| after the step, m
    "relative_speed",  # ||X_E-dot (mean over the step) - X_T-dot||, m/s
    "estimate_position_error",  # m, NaN without a valid estimate
    "estimate_velocity_error",  # m/s
    "estimate_nees",  # NEES of (position, velocity), NaN without a covariance
    "saturated",  # a joint moved at (nearly) its rate limit
    "clipped",  # the world clipped the requested increment
    "path_length",  # end-effector path since reset, m
    "target_visible",  # every marker in view at this step's capture
    "estimator_status",  # one of capture_bench.sensing.estimator.STATUSES
)
#: ``info`` of the step that ends an episode, in addition.
END_INFO_KEYS = ("physical_limit_time",)  # s, the episode's bound (inf: none)
#: ``info`` of ``reset``.
RESET_INFO_KEYS = ("time", "distance")
#: Keys whose "none" is None in the single env and NaN in the vector env.
OPTIONAL_KEYS = ("capture_time", "capture_time_estimated")


def info_keys(reward_mode: str) -> tuple[str, ...]:
    """The ``info`` keys of every step under ``reward_mode``: :data:`INFO_KEYS`, then the
    mode's reward terms."""
    return INFO_KEYS + REWARD_TERMS[reward_mode]


@dataclass
class ArmState:
    """What the rule carries from one step to the next for N episodes (arrays, row i episode i).

    Attributes:
        theta: joint angles, rad, (N, 3).
        x_e: end-effector position X_E, global, m, (N, 3).
        distance: true ||X_E - X_T||, m, (N,).
        path_length: end-effector path since reset, m, (N,).
        since_frame: time without a usable frame, s, (N,).
        unreachable_for: time with X_T outside the arm's reach, s, (N,).
        capture_time_estimated: s, NaN until the capture test completes on the estimate, (N,).
        inside_since: when the stay inside eq. 20's box (true target) in progress at the last
            step's end began, s; NaN if outside then, (N,).
        estimate_inside_since: the same for the estimated target, (N,).
    """

    theta: FloatArray
    x_e: FloatArray
    distance: FloatArray
    path_length: FloatArray
    since_frame: FloatArray
    unreachable_for: FloatArray
    capture_time_estimated: FloatArray
    inside_since: FloatArray
    estimate_inside_since: FloatArray

    @classmethod
    def empty(cls, n: int) -> ArmState:
        """N episodes, none started."""
        zeros = np.zeros(n)
        return cls(
            np.zeros((n, 3)),
            np.zeros((n, 3)),
            zeros.copy(),
            zeros.copy(),
            zeros.copy(),
            zeros,
            np.full(n, np.nan),
            np.full(n, np.nan),
            np.full(n, np.nan),
        )


@dataclass
class StepOutcome:
    """What :meth:`StepRule.step` decided for the M episodes that stepped (arrays (M,)).

    ``failure`` holds codes into :data:`FAILURE_NAMES`; ``info`` the (M,) values of
    :func:`info_keys` (``failure`` and ``estimator_status`` as object arrays of names, the
    optional times NaN where none).
    """

    reward: FloatArray
    terminated: BoolArray
    truncated: BoolArray
    failure: NDArray[np.int64]
    info: dict[str, NDArray]


class StepRule:
    """The rules of a step of ``scenario``'s task, for any number of episodes.

    Args:
        scenario: lost_after, the time limit, the control period, the capture's hold and the
            estimator's source.
        description: the task (arm, t_s, capture tolerance epsilon).
        reward_mode: one of :data:`capture_bench.task.rewards.REWARD_MODES`.
    """

    def __init__(self, scenario: Scenario, description: TaskDescription, reward_mode: str):
        if reward_mode not in REWARD_MODES:
            raise ValueError(f"reward must be one of {REWARD_MODES}, got {reward_mode!r}")
        self.reward_mode = reward_mode
        self.info_keys = info_keys(reward_mode)
        self.set_tolerance(description.capture_tolerance)
        self.hold = scenario.capture.hold  # s
        self.control_period = description.control_period
        self.home = description.arm.home
        self.lost_after = scenario.lost_after + TIME_SLACK
        self.time_limit = time_limit(scenario.control)
        self.frames_matter = scenario.estimator.source != "truth"  # target_lost needs a camera

    def set_hold(self, hold: float) -> None:
        """Ask a capture to hold ``hold`` s (0: the first entry captures) from the next step on.
        Only a training curriculum does this (:class:`capture_bench.training.callbacks.
        HoldCurriculum`); an env built from its scenario asks for the scenario's
        ``capture.hold``."""
        value = float(hold)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"capture hold must be finite and >= 0 s, got {hold!r}")
        self.hold = value

    def set_tolerance(self, tolerance: Any) -> None:
        """Test eq. 20 with ``tolerance`` (m, a number or (3,)) from the next step on. Only a
        training curriculum does this (:class:`capture_bench.training.callbacks.
        ToleranceCurriculum`); an env built from its scenario tests the scenario's epsilon."""
        eps = np.broadcast_to(np.asarray(tolerance, dtype=float), (3,)).copy()
        if not (np.isfinite(eps).all() and (eps > 0).all()):
            raise ValueError(f"capture tolerance must be finite and > 0, got {tolerance!r}")
        self.tolerance = eps
        self.tolerance_radius = float(np.linalg.norm(eps))

    def start(self, state: ArmState, rows: Rows, target_position: FloatArray) -> dict[str, NDArray]:
        """Begin episodes ``rows`` at the home pose; ``target_position`` X_T at reset, (M, 3).
        Returns their reset ``info`` values (:data:`RESET_INFO_KEYS`), (M,) each."""
        x_e = kinematics.forward_kinematics_point(self.home)
        state.theta[rows] = self.home
        state.x_e[rows] = x_e
        state.path_length[rows] = state.since_frame[rows] = state.unreachable_for[rows] = 0.0
        state.capture_time_estimated[rows] = np.nan
        state.inside_since[rows] = state.estimate_inside_since[rows] = np.nan
        distance = np.linalg.norm(x_e - target_position, axis=1)
        state.distance[rows] = distance
        return {"time": np.zeros(distance.size), "distance": distance}

    def step(
        self,
        state: ArmState,
        rows: Rows,
        before: Mapping[str, NDArray],
        after: Mapping[str, NDArray],
        theta: FloatArray,
        x_e: FloatArray,
        clipped: BoolArray,
        saturated: BoolArray,
        collides: Callable[[BoolArray], BoolArray],
        trajectory: Callable[[int], TargetTrajectory],
    ) -> StepOutcome:
        """One step of the M episodes ``rows``, updating ``state`` in place.

        Args:
            state: the N episodes' state (rows ``rows`` step).
            rows: the stepping episodes (a slice or indices).
            before, after: the target side at the start and the end of the step, (M, ...) arrays
                by :data:`capture_bench.task.recording.STEP_TRACKS` name.
            theta, x_e: joint angles after the world's limits, rad, and X_E there, m, (M, 3).
            clipped, saturated: the world's flags, (M,).
            collides: given which of the M to ask (M,) bool, whether each is in collision (the
                world; asked only where the step did not capture).
            trajectory: the true trajectory of the j-th stepping episode (for the arc test).
        """
        dt, time, x_t = after["dt"], after["time"], after["position"]
        # copies: with a slice for ``rows`` these would be views of what the step overwrites
        theta0, x_e0 = state.theta[rows].copy(), state.x_e[rows].copy()
        d_prev = state.distance[rows].copy()
        state.theta[rows], state.x_e[rows] = theta, x_e
        state.path_length[rows] += np.linalg.norm(x_e - x_e0, axis=1)
        t0 = time - dt

        capture_time, state.inside_since[rows] = self.capture_times(
            theta0,
            theta - theta0,
            x_e0 - before["position"],
            x_e - x_t,
            t0,
            dt,
            trajectory,
            state.inside_since[rows],
        )
        captured = ~np.isnan(capture_time)
        self._estimated_capture(state, rows, before, after, x_e0, x_e, t0, dt)
        failure = self.failures(state, rows, after, captured, collides)
        ended = captured | (failure != 0)
        timeout = ~ended & (time >= self.time_limit)
        failure[timeout] = TIMEOUT

        distance = np.linalg.norm(x_e - x_t, axis=1)
        state.distance[rows] = distance
        penalised = _PENALISED[failure]
        terms = reward_terms(self.reward_mode, d_prev, distance, captured, penalised)
        v_e = (x_e - x_e0) / dt[:, None]  # mean end-effector velocity over the step
        info: dict[str, NDArray] = {
            "is_success": captured,
            "failure": FAILURE_NAMES[failure],
            "capture_time": capture_time,
            "capture_time_estimated": state.capture_time_estimated[rows].copy(),
            "time": time,
            "dt": dt,
            "distance": distance,
            "relative_speed": np.linalg.norm(v_e - after["velocity"], axis=1),
            "estimate_position_error": after["position_error"],
            "estimate_velocity_error": after["velocity_error"],
            "estimate_nees": after["nees"],
            "saturated": saturated,
            "clipped": clipped,
            "path_length": state.path_length[rows].copy(),
            "target_visible": after["visible"],
            "estimator_status": _STATUS_NAMES[after["estimator_status"]],
            **terms,
        }
        return StepOutcome(total_reward(terms), ended, timeout, failure, info)

    def step_scalar(
        self,
        state: ArmState,
        episode: RecordedEpisode,
        k: int,
        theta: FloatArray,
        x_e: FloatArray,
        clipped: bool,
        saturated: bool,
        collides: Callable[[], bool],
        trajectory: TargetTrajectory,
    ) -> tuple[float, bool, bool, dict[str, Any]]:
        """:meth:`step` for one episode (row 0 of ``state``), in scalar Python: the single env's
        fast path (at one row numpy's per-call overhead is most of the rule's cost; measured by
        ``benchmarks/bench_env.py``). The same rules in the same order; ``tests/test_step_rule.py``
        checks it equal to :meth:`step`, value for value.

        Args:
            state: one episode's state, updated in place.
            episode: its target side; ``k`` the step that ends now (``k - 1`` its start).
            theta, x_e: joint angles after the world's limits, rad, and X_E there, m, (3,).
            clipped, saturated: the world's flags.
            collides: whether the arm is in collision now (asked only if it did not capture).
            trajectory: the episode's true trajectory (for the arc test).

        Returns:
            ``(reward, terminated, truncated, info)``, ``info`` as the single env gives it:
            Python scalars, None for no capture or no failure.
        """
        dt, time = float(episode.dt[k]), float(episode.time[k])
        x_t, x_t0 = episode.position[k], episode.position[k - 1]
        theta0, x_e0 = state.theta[0].copy(), state.x_e[0].copy()
        d_prev = float(state.distance[0])
        state.theta[0], state.x_e[0] = theta, x_e
        path_length = float(state.path_length[0]) + segment_length(x_e0, x_e)
        state.path_length[0] = path_length
        t0 = time - dt

        capture_time, since = self.capture_time_scalar(
            theta0, theta - theta0, x_e0 - x_t0, x_e - x_t, t0, dt, trajectory,
            float(state.inside_since[0]),
        )  # fmt: skip
        state.inside_since[0] = since
        captured = capture_time is not None
        estimated = float(state.capture_time_estimated[0])
        if math.isnan(estimated):
            since = math.nan
            if episode.estimate_valid[k - 1] and episode.estimate_valid[k]:
                interval = inside_interval(
                    x_e0 - episode.estimate_position[k - 1],
                    x_e - episode.estimate_position[k],
                    self.tolerance,
                )
                if interval is not None:
                    done, since = held_capture(
                        (interval,), float(state.estimate_inside_since[0]), t0, dt, self.hold
                    )
                    if done is not None:
                        estimated = done
                        state.capture_time_estimated[0] = estimated
            state.estimate_inside_since[0] = since
        failure = self.failure_scalar(state, episode, k, captured, collides)
        ended = captured or failure != 0
        timeout = not ended and time >= self.time_limit
        if timeout:
            failure = TIMEOUT

        distance = segment_length(x_e, x_t)
        state.distance[0] = distance
        terms = reward_terms(self.reward_mode, d_prev, distance, captured, _PENALISED[failure])
        info: dict[str, Any] = {
            "is_success": captured,
            "failure": FAILURE_NAMES[failure],
            "capture_time": capture_time,
            "capture_time_estimated": None if math.isnan(estimated) else estimated,
            "time": time,
            "dt": dt,
            "distance": distance,
            "relative_speed": segment_length((x_e - x_e0) / dt, episode.velocity[k]),
            "estimate_position_error": float(episode.position_error[k]),
            "estimate_velocity_error": float(episode.velocity_error[k]),
            "estimate_nees": float(episode.nees[k]),
            "saturated": saturated,
            "clipped": clipped,
            "path_length": path_length,
            "target_visible": bool(episode.visible[k]),
            "estimator_status": STATUSES[episode.estimator_status[k]],
            **{name: float(value) for name, value in terms.items()},
        }
        return float(total_reward(terms)), ended, timeout, info

    def capture_time_scalar(
        self,
        theta0: FloatArray,
        applied: FloatArray,
        d0: FloatArray,
        d1: FloatArray,
        t0: float,
        dt: float,
        trajectory: TargetTrajectory,
        since: float,
    ) -> tuple[float | None, float]:
        """:meth:`capture_times` for one step, with the scalar tests of ``capture.py``: the
        capture time (None where the capture did not complete) and the stay's start at the
        step's end (NaN: outside)."""
        sag = arc_sag_bound(applied)
        if sag <= ARC_RESOLUTION:
            interval = inside_interval(d0, d1, self.tolerance)
            intervals = [] if interval is None else [interval]
        elif closest_approach(d0, d1) > self.tolerance_radius + sag:
            return None, math.nan  # the arc stays within `sag` of the chord: never inside
        else:
            intervals = inside_intervals_along_arc(
                theta0, applied, lambda f: trajectory.position(t0 + f * dt), self.tolerance
            )
        if not intervals:
            return None, math.nan
        return held_capture(intervals, since, t0, dt, self.hold)

    def failure_scalar(
        self,
        state: ArmState,
        episode: RecordedEpisode,
        k: int,
        captured: bool,
        collides: Callable[[], bool],
    ) -> int:
        """:meth:`failures` for one step (row 0 of ``state``, step ``k`` of ``episode``)."""
        dt = float(episode.dt[k])
        failure = COLLISION if not captured and collides() else 0
        unreachable_for = 0.0 if episode.reachable[k] else float(state.unreachable_for[0]) + dt
        state.unreachable_for[0] = unreachable_for
        if failure == 0 and not captured and unreachable_for > self.lost_after:
            failure = UNREACHABLE
        if self.frames_matter:
            usable = episode.estimator_status[k] == _STATUS_OK
            since = 0.0 if usable else float(state.since_frame[0]) + dt
            state.since_frame[0] = since
            if failure == 0 and not captured and since > self.lost_after:
                failure = TARGET_LOST
        return failure

    def observe_scalar(
        self, state: ArmState, episode: RecordedEpisode, k: int
    ) -> NDArray[np.float32]:
        """:meth:`observe` of one episode (row 0 of ``state``) at step ``k`` of ``episode``."""
        x_e = state.x_e[0]
        if episode.estimate_valid[k]:
            position, velocity = episode.estimate_position[k], episode.estimate_velocity[k]
        else:
            position, velocity = x_e, np.zeros(3)
        return encode_observation(
            position, velocity, x_e, state.theta[0], float(episode.dt[k]), self.control_period
        )

    def capture_times(
        self,
        theta0: FloatArray,
        applied: FloatArray,
        d0: FloatArray,
        d1: FloatArray,
        t0: FloatArray,
        dt: FloatArray,
        trajectory: Callable[[int], TargetTrajectory],
        since: FloatArray,
    ) -> tuple[FloatArray, FloatArray]:
        """When each step's capture completed (NaN where it did not) and when the stay inside
        eq. 20's box in progress at its end began (NaN: outside), on the true target
        (:mod:`capture_bench.task.capture`): the stays are tested on the chord where the arc sags
        by at most ``ARC_RESOLUTION``, else along the arc where the chord passes near enough;
        :func:`~capture_bench.task.capture.held_capture` then applies the hold.

        Args:
            theta0, applied: joint angles at the start and the increment, rad, (M, 3).
            d0, d1: X_E - X_T at the start and the end, m, (M, 3).
            t0, dt: the step's start and real period, s, (M,).
            trajectory: the j-th episode's true trajectory.
            since: when the stay in progress at the step's start began, s, NaN if none, (M,).
        """
        lo, hi = inside_intervals(d0, d1, self.tolerance)
        sag = arc_sag_bounds(applied)
        arc = sag > ARC_RESOLUTION
        near = arc & ~(closest_approaches(d0, d1) > self.tolerance_radius + sag)
        capture_time = np.full(lo.size, np.nan)
        since_after = np.full(lo.size, np.nan)
        # Only steps that are inside the box at some time (rare: near the target) need the walk.
        for j in np.flatnonzero((~arc & ~np.isnan(lo)) | near).tolist():
            if arc[j]:  # along the true arc
                traj, start, step = trajectory(j), float(t0[j]), float(dt[j])

                def target_at(f: FloatArray, traj=traj, start=start, step=step) -> FloatArray:
                    return traj.position(start + f * step)

                intervals = inside_intervals_along_arc(
                    theta0[j], applied[j], target_at, self.tolerance
                )
            else:
                intervals = [(float(lo[j]), float(hi[j]))]
            done, since_after[j] = held_capture(
                intervals, float(since[j]), float(t0[j]), float(dt[j]), self.hold
            )
            if done is not None:
                capture_time[j] = done
        return capture_time, since_after

    def _estimated_capture(self, state, rows, before, after, x_e0, x_e, t0, dt) -> None:
        """Record the first time the capture test (and its hold) completed on the estimated
        target, along the chord between the step's estimates (both ends valid; a step without
        them breaks the stay)."""
        pending = np.isnan(state.capture_time_estimated[rows])
        where = np.arange(state.distance.size)[rows][pending]
        since = state.estimate_inside_since[where].copy()
        state.estimate_inside_since[where] = np.nan
        valid = (before["estimate_valid"] & after["estimate_valid"])[pending]
        if not valid.any():
            return
        lo, hi = inside_intervals(
            (x_e0 - before["estimate_position"])[pending][valid],
            (x_e - after["estimate_position"])[pending][valid],
            self.tolerance,
        )
        start, step = t0[pending][valid], dt[pending][valid]
        rows_valid, since_valid = where[valid], since[valid]
        for j in np.flatnonzero(~np.isnan(lo)).tolist():
            done, state.estimate_inside_since[rows_valid[j]] = held_capture(
                [(float(lo[j]), float(hi[j]))],
                float(since_valid[j]),
                float(start[j]),
                float(step[j]),
                self.hold,
            )
            if done is not None:
                state.capture_time_estimated[rows_valid[j]] = done

    def failures(
        self,
        state: ArmState,
        rows: Rows,
        after: Mapping[str, NDArray],
        captured: BoolArray,
        collides: Callable[[BoolArray], BoolArray],
    ) -> NDArray[np.int64]:
        """The failure code of each step that did not capture, in the order collision,
        unreachable (X_T out of reach for more than ``lost_after``), target_lost (no usable
        frame for more than ``lost_after``); 0 for none. Updates the two timers."""
        dt = after["dt"]
        failure = np.zeros(captured.size, dtype=np.int64)
        failure[collides(~captured)] = COLLISION
        unreachable_for = np.where(after["reachable"], 0.0, state.unreachable_for[rows] + dt)
        state.unreachable_for[rows] = unreachable_for
        failure[(failure == 0) & ~captured & (unreachable_for > self.lost_after)] = UNREACHABLE
        if self.frames_matter:
            usable = after["estimator_status"] == _STATUS_OK
            since = np.where(usable, 0.0, state.since_frame[rows] + dt)
            state.since_frame[rows] = since
            failure[(failure == 0) & ~captured & (since > self.lost_after)] = TARGET_LOST
        return failure

    def observe(
        self, state: ArmState, rows: Rows, now: Mapping[str, NDArray]
    ) -> NDArray[np.float32]:
        """The observations of episodes ``rows`` (M, 16) given the target side ``now`` (their
        current step's rows): the estimate where valid, else X_E with zero velocity, and the
        last real period (t_s at reset)."""
        x_e = state.x_e[rows]
        valid = now["estimate_valid"][:, None]
        return encode_observations(
            np.where(valid, now["estimate_position"], x_e),
            np.where(valid, now["estimate_velocity"], 0.0),
            x_e,
            state.theta[rows],
            now["dt"],
            self.control_period,
        )


def scalar_info(values: Mapping[str, NDArray], j: int = 0) -> dict[str, Any]:
    """Episode j's ``info`` as the single env gives it: Python scalars, None for no failure and
    for the :data:`OPTIONAL_KEYS` where NaN."""
    out: dict[str, Any] = {}
    for key, array in values.items():
        value = array[j]
        out[key] = value.item() if isinstance(value, np.generic) else value
    for key in OPTIONAL_KEYS:
        if key in out and math.isnan(out[key]):
            out[key] = None
    return out
