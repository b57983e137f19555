"""The task's rules for one control step, over N episodes at once (numpy): written once, for
``CaptureVectorEnv`` and ``CaptureEnv`` (its N = 1 case).

The model is Gymnasium's functional CartPole (``gymnasium/envs/phys2d/cartpole.py``), whose one
transition function serves both its single and its vector env. Here the envs do the simulation's
half of a step (the world's rate and joint limits, forward kinematics, the collision query) and
read the target's half from a `RecordedEpisode`; then
`StepRule.step` applies the rules:

* capture (eq. 20, ``|X_E - X_T| < epsilon`` component-wise) on the *true* target, tested along
  the end-effector's arc over the whole step (`capture_bench.task.capture`); with a speed
  bound (``capture.v_max`` m/s: the capture envelope) the end-effector's instantaneous velocity
  relative to the capture point must be at most ``v_max`` too, along the arc; with a hold
  (``capture.hold`` s of the scenario) both must hold without a break for that long, and the
  capture is when the hold completes (`held_capture`; the
  stay in progress is carried in `ArmState`);
* eq. 20 and its hold on the *estimated* target, the first time they complete
  (``capture_time_estimated``: what the paper's hardware could judge; without the speed bound);
* the failure, in this order: ``collision``, ``unreachable``, ``target_lost`` (each only if the
  step did not capture), then ``timeout`` at the time limit (a truncation);
* the reward terms (`capture_bench.task.rewards`);
* the ``info`` entries (`INFO_KEYS`, then the reward terms; `END_INFO_KEYS` where an
  episode ended, filled by the env, which owns the bound);
* the observation (`capture_bench.task.observation`, eq. 13's predicted relative vector).

Adding an ``info`` key, a reward term, an observation entry or a failure reason is an edit here
(or in ``rewards.py`` / ``observation.py``); tests check both envs expose exactly these sets.

At N = 1 numpy's per-call overhead, not the arithmetic, is a step's cost, so a step makes few
numpy calls: the capture tests run in full only for the steps that a cheap bound
(`approach_lower_bounds`) does not already put out of reach
(a step far from the target, the common case, costs the bound alone), and each piece of state
is read once and written once.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from capture_bench.sensing.estimator import STATUSES
from capture_bench.sim import kinematics
from capture_bench.sim.kinematics import ArmPose
from capture_bench.sim.target_motion import TargetTrajectory
from capture_bench.task.capture import (
    ARC_RESOLUTION,
    approach_lower_bounds,
    arc_sag_bounds,
    closest_approaches,
    held_capture,
    inside_intervals,
    inside_intervals_along_arcs,
    intersect,
    relative_velocities,
    row_norms,
    slow_intervals_along_arc,
    speeds_between,
)
from capture_bench.task.episode import TIME_SLACK, time_limit
from capture_bench.task.observation import TaskDescription, encode_observation
from capture_bench.task.rewards import (
    REWARD_MODES,
    REWARD_TERMS,
    SPEED_REACH,
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
_NONE = np.int64(0)  # the failure code of no failure
_STATUS_OK = np.int8(STATUSES.index("ok"))
_STATUS_NAMES = np.array(STATUSES, dtype=object)
# m: slack on the screen of the capture tests, far above the bound's rounding (~1e-17 m), far
# below anything eq. 20 resolves
_SCREEN_MARGIN = 1e-9

#: The tracks of the target side `StepRule.step` reads at a step's start (``before``); at
#: its end (``after``) it reads every one of `capture_bench.task.recording.STEP_TRACKS`.
BEFORE_TRACKS = ("position", "velocity", "estimate_valid", "estimate_position")

#: ``info`` of every step, in this order (the reward terms of the mode follow).
INFO_KEYS = (
    "is_success",  # the capture completed during the step (eq. 20 on the true target, held)
    "failure",  # None or one of FAILURES
    "capture_time",  # s, when the capture completed (None / NaN: no capture)
    "capture_time_estimated",  # s, the same test first completed on the estimate (None / NaN)
    "time",  # s since reset
    "dt",  # the step's real control period, s
    "distance",  # true ||X_E - X_T|| after the step, m
    # |J(theta) dtheta/dt - Xdot_T| at the step's end: the end-effector's instantaneous speed
    # relative to the capture point, m/s
    "relative_speed",
    "distance_at_capture",  # true ||X_E - X_T|| at the capture instant, m (None / NaN)
    "relative_speed_at_capture",  # the instantaneous relative speed then, m/s (None / NaN)
    # the largest instantaneous relative speed over the hold, from the captured stay's entry to
    # the capture, m/s (hold 0: relative_speed_at_capture; None / NaN)
    "relative_speed_max_over_hold",
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
OPTIONAL_KEYS = (
    "capture_time",
    "capture_time_estimated",
    "distance_at_capture",
    "relative_speed_at_capture",
    "relative_speed_max_over_hold",
)


def info_keys(reward_mode: str) -> tuple[str, ...]:
    """The ``info`` keys of every step under ``reward_mode``: `INFO_KEYS`, then the
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
        stay_speed_max: the largest instantaneous relative speed over the stay of
            ``inside_since`` up to the last step's end, m/s, sampled as
            `StepRule.capture_times` says; NaN where no stay is in progress, (N,).
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
    stay_speed_max: FloatArray

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
            np.full(n, np.nan),
        )


class Captures(NamedTuple):
    """What `StepRule.capture_times` found for M steps on the true target, (M,) arrays,
    NaN where none.

    Attributes:
        time: when the capture completed, s.
        since: when the stay in progress at the step's end began, s (on a capture, the captured
            stay's entry).
        stay_speed_max: the largest instantaneous relative speed over the stay in progress at
            the step's end, up to that end, m/s (NaN on a capture).
        distance: true ||X_E - X_T|| at the capture instant, m.
        speed: the instantaneous relative speed |J(theta) dtheta/dt - Xdot_T| then, m/s.
        speed_max: the largest instantaneous relative speed over the hold, from the captured
            stay's entry to the capture, m/s (hold 0: ``speed``).
    """

    time: FloatArray
    since: FloatArray
    stay_speed_max: FloatArray
    distance: FloatArray
    speed: FloatArray
    speed_max: FloatArray


@dataclass
class StepOutcome:
    """What `StepRule.step` decided for the M episodes that stepped (arrays (M,)).

    ``failure`` holds codes into `FAILURE_NAMES`; ``info`` the (M,) values of
    `info_keys` (``failure`` and ``estimator_status`` as object arrays of names, the
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
        reward_mode: one of `capture_bench.task.rewards.REWARD_MODES`.
    """

    def __init__(self, scenario: Scenario, description: TaskDescription, reward_mode: str):
        if reward_mode not in REWARD_MODES:
            raise ValueError(f"reward must be one of {REWARD_MODES}, got {reward_mode!r}")
        self.reward_mode = reward_mode
        self.info_keys = info_keys(reward_mode)
        self.set_tolerance(description.capture_tolerance)
        self.hold = scenario.capture.hold  # s
        v_max = scenario.capture.v_max
        self.v_max = math.inf if v_max is None else float(v_max)  # m/s
        self.control_period = description.control_period
        self.home = description.arm.home
        # numpy scalars: an array compares with one faster than with a Python float
        self.lost_after = np.float64(scenario.lost_after + TIME_SLACK)
        self.time_limit = np.float64(time_limit(scenario.control))
        self.frames_matter = scenario.estimator.source != "truth"  # target_lost needs a camera

    def set_hold(self, hold: float) -> None:
        """Ask a capture to hold ``hold`` s (0: the first entry captures) from the next step on.
        Only a training curriculum does this (`capture_bench.training.callbacks.
        HoldCurriculum`); an env built from its scenario asks for the scenario's
        ``capture.hold``."""
        value = float(hold)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"capture hold must be finite and >= 0 s, got {hold!r}")
        self.hold = value

    def set_tolerance(self, tolerance: Any) -> None:
        """Test eq. 20 with ``tolerance`` (m, a number or (3,)) from the next step on. Only a
        training curriculum does this (`capture_bench.training.callbacks.
        ToleranceCurriculum`); an env built from its scenario tests the scenario's epsilon."""
        eps = np.broadcast_to(np.asarray(tolerance, dtype=float), (3,)).copy()
        if not (np.isfinite(eps).all() and (eps > 0).all()):
            raise ValueError(f"capture tolerance must be finite and > 0, got {tolerance!r}")
        self.tolerance = eps
        self.tolerance_radius = np.float64(np.linalg.norm(eps))
        self._screen_radius = self.tolerance_radius + _SCREEN_MARGIN

    def start(self, state: ArmState, rows: Rows, target_position: FloatArray) -> dict[str, NDArray]:
        """Begin episodes ``rows`` at the home pose; ``target_position`` X_T at reset, (M, 3).
        Returns their reset ``info`` values (`RESET_INFO_KEYS`), (M,) each."""
        x_e = kinematics.forward_kinematics(self.home)
        state.theta[rows] = self.home
        state.x_e[rows] = x_e
        state.path_length[rows] = state.since_frame[rows] = state.unreachable_for[rows] = 0.0
        state.capture_time_estimated[rows] = np.nan
        state.inside_since[rows] = state.estimate_inside_since[rows] = np.nan
        state.stay_speed_max[rows] = np.nan
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
        pose: ArmPose,
        clipped: BoolArray,
        saturated: BoolArray,
        collides: Callable[[BoolArray], BoolArray],
        trajectory: Callable[[int], TargetTrajectory],
    ) -> StepOutcome:
        """One step of the M episodes ``rows``, updating ``state`` in place.

        Args:
            state: the N episodes' state (rows ``rows`` step).
            rows: the stepping episodes (a slice or indices).
            before: the target side at the start of the step, (M, ...) arrays by
                `BEFORE_TRACKS` name (more are ignored).
            after: the target side at the end of the step, (M, ...) arrays by
                `capture_bench.task.recording.STEP_TRACKS` name.
            theta, pose: joint angles after the world's limits, rad, (M, 3), and the arm there
                (`ArmPose`: X_E and the trigonometry of eq. 8 and its Jacobian).
            clipped, saturated: the world's flags, (M,).
            collides: given which of the M to ask (M,) bool, whether each is in collision (the
                world; asked only where the step did not capture).
            trajectory: the true trajectory of the j-th stepping episode (for the arc test).
        """
        dt, time, x_t, x_e = after["dt"], after["time"], after["position"], pose.x_e
        # The state at the step's start (views of it where ``rows`` is a slice): written back
        # only once every use below has read it.
        theta0, x_e0, d_prev = state.theta[rows], state.x_e[rows], state.distance[rows]
        applied = theta - theta0
        moved = x_e - x_e0
        d0 = x_e0 - before["position"]
        d1 = x_e - x_t
        t0 = time - dt
        reach = approach_lower_bounds(d0, d1)  # a lower bound on the step's closest approach
        capture = self.capture_times(
            theta0,
            applied,
            d0,
            d1,
            t0,
            dt,
            trajectory,
            state.inside_since[rows],
            reach=reach,
            positions=(before["position"], x_t),
            velocities=(before["velocity"], after["velocity"]),
            speed_max=state.stay_speed_max[rows],
        )
        capture_time = capture.time
        captured = capture_time == capture_time  # not NaN
        estimated = self._estimated_capture(state, rows, before, after, x_e0, x_e, t0, dt)
        failure = self.failures(state, rows, after, captured, collides)
        ended = captured | (failure != _NONE)
        timeout = time >= self.time_limit
        if np.count_nonzero(timeout):
            timeout &= ~ended
            failure[timeout] = TIMEOUT

        # the end-effector's instantaneous velocity relative to the capture point at the end
        end_velocity = relative_velocities(pose, applied / dt[:, None], after["velocity"])
        # |X_E - X_T|, the step's length and the relative speed at its end: one norm
        lengths = row_norms(np.concatenate((d1, moved, end_velocity), axis=1))
        distance, relative_speed = lengths[:, 0], lengths[:, 2]
        path_length = state.path_length[rows] + lengths[:, 1]
        terms = reward_terms(
            self.reward_mode,
            d_prev,
            distance,
            captured,
            _PENALISED[failure],
            relative_speed=relative_speed,
            closest=self._closest(d0, d1, reach),
            speed_limit=self.v_max,
        )
        info: dict[str, NDArray] = {
            "is_success": captured,
            "failure": FAILURE_NAMES[failure],
            "capture_time": capture_time,
            "capture_time_estimated": estimated,
            "time": time,
            "dt": dt,
            "distance": distance,
            "relative_speed": relative_speed,
            "distance_at_capture": capture.distance,
            "relative_speed_at_capture": capture.speed,
            "relative_speed_max_over_hold": capture.speed_max,
            "estimate_position_error": after["position_error"],
            "estimate_velocity_error": after["velocity_error"],
            "estimate_nees": after["nees"],
            "saturated": saturated,
            "clipped": clipped,
            "path_length": path_length,
            "target_visible": after["visible"],
            # int8 codes: take() costs a third of indexing with them
            "estimator_status": _STATUS_NAMES.take(after["estimator_status"]),
            **terms,
        }
        state.theta[rows], state.x_e[rows], state.distance[rows] = theta, x_e, distance
        state.path_length[rows], state.inside_since[rows] = path_length, capture.since
        state.stay_speed_max[rows] = capture.stay_speed_max
        return StepOutcome(total_reward(terms), ended, timeout, failure, info)

    def _closest(self, d0: FloatArray, d1: FloatArray, reach: FloatArray) -> FloatArray:
        """The reward's closeness: the closest approach of X_E - X_T over each step, on the
        straight segment between its ends, m (`
        closest_approaches`); inf where the step's lower bound ``reach`` puts it beyond
        `SPEED_REACH` (the speed term's weight is below 2.1e-9
        there), and everywhere where the speed term is 0 anyway: under the sparse reward, and
        without a speed bound."""
        if self.reward_mode == "sparse" or self.v_max == math.inf:
            return np.full(reach.size, np.inf)
        near = reach <= SPEED_REACH
        count = np.count_nonzero(near)
        if count == reach.size:  # every step near (the single env's near steps): no indexing
            return closest_approaches(d0, d1)
        closest = np.full(reach.size, np.inf)
        if count:
            closest[near] = closest_approaches(d0[near], d1[near])
        return closest

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
        *,
        reach: FloatArray,
        positions: tuple[FloatArray, FloatArray],
        velocities: tuple[FloatArray, FloatArray],
        speed_max: FloatArray,
    ) -> Captures:
        """When each step's capture completed (NaN where it did not) and when the stay inside
        eq. 20's box in progress at its end began (NaN: outside), on the true target
        (`capture_bench.task.capture`): the stays are tested on the chord where the arc sags
        by at most ``ARC_RESOLUTION``, else along the arc where the chord passes within the
        tolerance's radius plus the sag; with ``v_max`` the stays are cut to where the
        end-effector's instantaneous velocity relative to the capture point is at most
        ``v_max`` (the capture envelope); `held_capture` then
        applies the hold. The steps whose lower bound ``reach`` (`approach_lower_bounds`) puts
        farther than that cannot enter the box and are not
        tested.

        On each step with a stay (the one `held_capture`
        keeps: inside the box, and slow where ``v_max`` bounds the speed) it also takes the
        instantaneous relative speed ``|J(theta) dtheta/dt - Xdot_T|`` over the stay's part of
        the step, from its entry (or the step's start) to the capture (or the step's end),
        sampled by `speeds_between` (the part's ends and the
        points of the speed test's grid between them; the largest is within
        ``2 VELOCITY_RESOLUTION`` of the true largest), and joins its largest to
        ``speed_max`` where the stay goes on from the last step; on a capture, the distance and
        the relative speed at the capture instant. The arm is then on its true arc,
        ``theta0 + s applied``; X_T and Xdot_T are taken straight between the step's ends
        (``positions``, ``velocities``), exact for Xdot_T wherever the target's velocity is
        linear in time over the step (a drift; an evasive target between two jinks), within
        ``dt^2 / 8`` times its third derivative otherwise (~1e-5 m/s at the shipped rates), and
        within ``|Delta a| dt / 4`` in a step holding an evasive jink (~4e-4 m/s at most).

        Args:
            theta0, applied: joint angles at the start and the increment, rad, (M, 3).
            d0, d1: X_E - X_T at the start and the end, m, (M, 3).
            t0, dt: the step's start and real period, s, (M,).
            trajectory: the j-th episode's true trajectory.
            since: when the stay in progress at the step's start began, s, NaN if none, (M,).
            reach: `approach_lower_bounds` of ``d0, d1``,
                m, (M,).
            positions, velocities: X_T and Xdot_T at the step's start and end, (M, 3) each.
            speed_max: the largest relative speed over the stay in progress at the step's start
                (`ArmState.stay_speed_max`), m/s, (M,).
        """
        out = Captures(*_nans(6 * d0.shape[0]).reshape(6, -1))  # six (M,) rows of one block
        sag = arc_sag_bounds(applied)
        near = reach - sag <= self._screen_radius
        if not np.count_nonzero(near):  # the common case
            return out
        steps = np.flatnonzero(near)
        lo, hi = inside_intervals(d0[steps], d1[steps], self.tolerance)
        closest = closest_approaches(d0[steps], d1[steps])
        stays: dict[int, list[tuple[float, float]]] = {}
        # Along the true arc where it sags from the chord and the chord passes near; all at once.
        arcs = [
            i
            for j, i in enumerate(steps.tolist())
            if sag[i] > ARC_RESOLUTION and closest[j] <= self.tolerance_radius + sag[i]
        ]
        if arcs:

            def target_at(i: int) -> Callable[[FloatArray], FloatArray]:
                traj, start, step = trajectory(i), float(t0[i]), float(dt[i])
                return lambda f: traj.position(start + f * step)

            along = inside_intervals_along_arcs(
                theta0[arcs], applied[arcs], [target_at(i) for i in arcs], self.tolerance
            )
            stays = dict(zip(arcs, along, strict=True))
        for j, i in enumerate(steps.tolist()):
            if sag[i] > ARC_RESOLUTION:
                if i not in stays:  # the chord passes too far for the arc to enter the box
                    continue
                intervals = stays[i]
            elif math.isnan(lo[j]):
                continue
            else:
                intervals = [(float(lo[j]), float(hi[j]))]
            if self.v_max < math.inf:  # the envelope: slow as well as inside
                intervals = intersect(intervals, self._slow(i, theta0, applied, t0, dt, trajectory))
            carried = float(since[i])
            done, start = held_capture(intervals, carried, float(t0[i]), float(dt[i]), self.hold)
            out.since[i] = start
            if done is not None or not math.isnan(start):  # a stay at the capture or the end
                goes_on = not math.isnan(carried) and start == carried  # from an earlier step
                self._stay_speeds(
                    out,
                    i,
                    (start, done),
                    float(speed_max[i]) if goes_on else math.nan,
                    (theta0[i], applied[i], float(t0[i]), float(dt[i])),
                    positions,
                    velocities,
                )
        return out

    @staticmethod
    def _stay_speeds(
        out: Captures,
        i: int,
        stay: tuple[float, float | None],
        speed_max: float,
        step: tuple[FloatArray, FloatArray, float, float],
        positions: tuple[FloatArray, FloatArray],
        velocities: tuple[FloatArray, FloatArray],
    ) -> None:
        """Row ``i`` of ``out``'s speeds over a stay (see `capture_times`).

        Args:
            out: where to write.
            i: the step's row.
            stay: when the stay began and when the capture completed (None: it goes on past
                the step's end), s.
            speed_max: the stay's largest relative speed before this step, m/s (NaN: it began
                in this step).
            step: the step's theta0, joint increment, start and real period.
            positions, velocities: X_T and Xdot_T at the steps' starts and ends, (M, 3) each.
        """
        (start, done), (theta0, applied, t0, dt) = stay, step
        end = 1.0 if done is None else min(max((done - t0) / dt, 0.0), 1.0)
        entry = min(max((start - t0) / dt, 0.0), end)
        v0, v1 = velocities[0][i], velocities[1][i]
        speeds = speeds_between(
            theta0, applied, dt, lambda f: (1.0 - f)[:, None] * v0 + f[:, None] * v1, entry, end
        )
        largest = float(speeds.max())
        if not math.isnan(speed_max):
            largest = max(largest, speed_max)
        if done is None:
            out.stay_speed_max[i] = largest
            return
        out.time[i] = done
        out.speed[i] = float(speeds[-1])
        out.speed_max[i] = largest
        x_e = kinematics.forward_kinematics(theta0 + end * applied)
        x_t = (1.0 - end) * positions[0][i] + end * positions[1][i]
        out.distance[i] = math.sqrt(float(np.dot(x_e - x_t, x_e - x_t)))

    def _slow(
        self,
        i: int,
        theta0: FloatArray,
        applied: FloatArray,
        t0: FloatArray,
        dt: FloatArray,
        trajectory: Callable[[int], TargetTrajectory],
    ) -> list[tuple[float, float]]:
        """The fractions of step ``i`` during which the end-effector's instantaneous velocity
        relative to the true capture point is at most ``v_max``
        (`slow_intervals_along_arc`)."""
        traj, start, step = trajectory(i), float(t0[i]), float(dt[i])
        return slow_intervals_along_arc(
            theta0[i], applied[i], step, lambda f: traj.velocity(start + f * step), self.v_max
        )

    def _estimated_capture(self, state, rows, before, after, x_e0, x_e, t0, dt) -> FloatArray:
        """Record the first time the capture test (and its hold) completed on the estimated
        target, along the chord between the step's estimates (both ends valid; a step without
        them breaks the stay); returns ``capture_time_estimated`` of the M episodes after the
        step (NaN: not yet), a new array."""
        estimated = state.capture_time_estimated[rows].copy()
        # The estimates are NaN where not valid, and so is their bound: the screen skips them.
        d0 = x_e0 - before["estimate_position"]
        d1 = x_e - after["estimate_position"]
        near = approach_lower_bounds(d0, d1) <= self._screen_radius
        if not np.count_nonzero(near):  # the common case
            state.estimate_inside_since[rows] = np.nan
            return estimated
        since = state.estimate_inside_since[rows]
        since_after = _nans(estimated.size)
        valid = before["estimate_valid"] & after["estimate_valid"]
        steps = np.flatnonzero(near & valid & np.isnan(estimated))
        lo, hi = inside_intervals(d0[steps], d1[steps], self.tolerance)
        for j, i in enumerate(steps.tolist()):
            if math.isnan(lo[j]):
                continue
            done, since_after[i] = held_capture(
                [(float(lo[j]), float(hi[j]))],
                float(since[i]),
                float(t0[i]),
                float(dt[i]),
                self.hold,
            )
            if done is not None:
                estimated[i] = done
        state.estimate_inside_since[rows] = since_after
        state.capture_time_estimated[rows] = estimated
        return estimated

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
        dt, going = after["dt"], ~captured
        collided = collides(going)
        # Each clock adds the step's period and restarts at 0 where its condition is clear (a
        # masked store: cheaper than np.where at one row, where numpy's per-call overhead is the
        # cost).
        unreachable_for = state.unreachable_for[rows] + dt
        unreachable_for[after["reachable"]] = 0.0
        state.unreachable_for[rows] = unreachable_for
        failure = np.zeros(captured.size, dtype=np.int64)
        unreachable = unreachable_for > self.lost_after
        if np.count_nonzero(unreachable):
            failure[going & unreachable] = UNREACHABLE
        if self.frames_matter:
            since = state.since_frame[rows] + dt
            since[after["estimator_status"] == _STATUS_OK] = 0.0  # a usable frame
            state.since_frame[rows] = since
            lost = since > self.lost_after
            if np.count_nonzero(lost):
                failure[going & lost & (failure == _NONE)] = TARGET_LOST
        if np.count_nonzero(collided):
            failure[collided] = COLLISION
        return failure

    def observe(
        self, state: ArmState, rows: Rows, now: Mapping[str, NDArray]
    ) -> NDArray[np.float32]:
        """The observations of episodes ``rows`` (M, 16) given the target side ``now`` (their
        current step's rows): the estimate where valid, else X_E with zero velocity, and the
        last real period (t_s at reset)."""
        x_e = state.x_e[rows]
        position, velocity = now["estimate_position"], now["estimate_velocity"]
        if np.count_nonzero(now["estimate_valid"]) < x_e.shape[0]:
            valid = now["estimate_valid"][:, None]
            position, velocity = np.where(valid, position, x_e), np.where(valid, velocity, 0.0)
        return encode_observation(
            position,
            velocity,
            x_e,
            state.theta[rows],
            now["dt"],
            self.control_period,
        )


def _nans(m: int) -> FloatArray:
    """(m,) NaN, a new array (np.full's work in two cheaper calls)."""
    out = np.empty(m)
    out.fill(np.nan)
    return out


def scalar_info(values: Mapping[str, NDArray], j: int = 0) -> dict[str, Any]:
    """Episode j's ``info`` as the single env gives it: Python scalars, None for no failure and
    for the `OPTIONAL_KEYS` where NaN."""
    out = {key: array.item(j) for key, array in values.items()}
    for key in OPTIONAL_KEYS:
        if key in out and math.isnan(out[key]):
            out[key] = None
    return out
