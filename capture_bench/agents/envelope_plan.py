"""Landing and tracking under the capture envelope, for a target trajectory given as functions of
time: the plan of the oracle's steps 2-3 (``capture_bench/agents/oracle.py``).

`EnvelopePlan` holds the trajectory ``X_T(t)``, ``Xdot_T(t)`` and the envelope (``v_max``, the
hold) and gives

* `EnvelopePlan.landing`: the step end ``t_m`` and the joint vector ``theta_m`` the arm
  reaches at full rate from ``theta0`` at t = 0, after which the approach and the tracking
  complete the capture first (of ``LANDING_CANDIDATES`` step ends from the last one before the
  entry by default, each simulated with the rule's own tests: `EnvelopePlan.simulate`);
* `EnvelopePlan.track_step`: one step of the approach and the tracking (the end-effector ends
  the step on ``X_T(t + dt)`` plus a relative position that moves at ``approach_speeds`` of
  ``v_max`` straight into eq. 20's box and on to the capture point).

It knows nothing but what it is given: the oracle gives it the true trajectory (privileged)
with time since the episode's start and ``theta0`` the home pose; ``planned_intercept`` gives it
the constant-velocity trajectory of the estimate, with time counted from its current step and
``theta0`` its current pose.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sim.kinematics import forward_kinematics, inverse_kinematics, within_limits
from capture_bench.task.capture import (
    held_capture,
    inside_intervals,
    inside_intervals_along_arc,
    intersect,
    slow_intervals_along_arc,
)
from capture_bench.task.observation import TaskDescription
from capture_bench.task.physical_limit import nearest_in_box

FloatArray = NDArray[np.float64]
#: The relative speeds of the slow approach, as fractions of ``v_max``, the fastest first.
APPROACH_SPEEDS = (0.99, 0.9, 0.6, 0.3, 0.0)
#: The approach aims at the nearest point of eq. 20's box shrunk to this fraction of epsilon.
APPROACH_DEPTH = 0.5
#: The landing point is the reachable point nearest eq. 20's box shrunk to this fraction.
LANDING_DEPTH = 0.98
#: Alternate projections between the reachable set and a box.
PROJECTIONS = 4
#: Step ends tried as the landing, from the last one before the entry.
LANDING_CANDIDATES = 6
#: Steps simulated after the hold's length before a landing counts as not capturing.
SIMULATED_STEPS = 6


@dataclass(frozen=True)
class EnvelopePlan:
    """The landing and the tracking of a capture of the trajectory ``position``, ``velocity``
    under the envelope ``v_max``, ``hold`` (module docstring).

    Attributes:
        description: the task's public description (the arm, t_s, epsilon).
        position: X_T(t), global, m: a time (s) -> (3,), times (N,) -> (N, 3).
        velocity: Xdot_T(t), global, m/s, the same shapes.
        v_max: the envelope's speed bound, m/s.
        hold: the envelope's hold, s.
        approach_speeds: the approach's relative speeds, fractions of ``v_max``, the fastest
            first (`track_step`).
        landing_depth: the landing aims at eq. 20's box shrunk to this fraction of epsilon.
        candidates: how many step ends `landing` tries, from the last one before the entry.
    """

    description: TaskDescription
    position: Callable[[ArrayLike], FloatArray]
    velocity: Callable[[ArrayLike], FloatArray]
    v_max: float
    hold: float
    approach_speeds: Sequence[float] = APPROACH_SPEEDS
    landing_depth: float = LANDING_DEPTH
    candidates: int = LANDING_CANDIDATES

    def at(self, t: float) -> FloatArray:
        """X_T(t), (3,)."""
        return np.asarray(self.position(float(t)), dtype=float).reshape(3)

    def landing(
        self, entry: float, theta_star: FloatArray, theta0: FloatArray, times: FloatArray,
        travel: FloatArray,
    ) -> tuple[float, FloatArray] | None:  # fmt: skip
        """The step end ``t_m`` and the joint vector ``theta_m`` the arm goes to at full rate
        from ``theta0`` at t = 0, after which the approach and the tracking complete the
        capture the earliest, or None if none of the candidates captures.

        Args:
            entry: the earliest entry into the envelope from which it can be held, s.
            theta_star: a joint vector at the entry, (3,).
            theta0: the joint vector at t = 0, (3,).
            times: the step ends, s, from t = 0 (the first), (K,).
            travel: how long the joints can have moved at full rate by each of ``times``, s.
        """
        arm = self.description.arm
        best: tuple[float, float, FloatArray] | None = None  # (capture, t_m, theta_m)
        first = max(int(np.searchsorted(times, entry)) - 1, 0)  # the last step end before
        for m in range(first, min(first + self.candidates, times.size - 1)):
            t_m = float(times[m])
            if best is not None and t_m + self.hold >= best[0]:
                break
            reach = arm.joint_rate_limits * travel[m]
            lo = np.maximum(arm.joint_lower, theta0 - reach)
            hi = np.minimum(arm.joint_upper, theta0 + reach)
            theta_m = self.landing_pose(self.at(t_m), theta_star, lo, hi)
            done = self.simulate(m, theta_m, times)
            if best is None or done < best[0]:
                best = (done, t_m, theta_m)
        if best is None or not np.isfinite(best[0]):
            return None
        return best[1], best[2]

    def landing_pose(
        self, goal: FloatArray, start: FloatArray, lo: FloatArray, hi: FloatArray
    ) -> FloatArray:
        """The joint vector of the box [lo, hi] to land on when the capture point is at ``goal``:
        of the joint vectors near eq. 20's box about ``goal`` shrunk to ``landing_depth``
        (`nearest_in_box_about` from ``start`` and from each IK solution of ``goal``), the one
        from which the approach (`approach_time`) enters eq. 20's box the soonest."""
        eps = self.description.capture_tolerance
        starts = np.vstack((start, distinct_solutions(goal)))
        q = nearest_in_box_about(
            starts, goal, self.landing_depth * eps, eps, lo, hi, self.landing_depth
        )
        speed = self.approach_speeds[0] * float(self.v_max)
        misses = forward_kinematics(q) - goal
        return q[int(np.argmin([approach_time(miss, eps, speed) for miss in misses]))]

    def simulate(self, m: int, theta_m: FloatArray, times: FloatArray) -> float:
        """When the capture completes if the arm is at ``theta_m`` at step end ``times[m]`` and
        then takes `track_step` every step (eq. 20's box and the speed bound along each step's
        arc, held for ``hold``, as the env tests them); inf if not within ``SIMULATED_STEPS``
        steps after the hold."""
        eps = self.description.capture_tolerance
        theta, since = theta_m, np.nan
        last = min(
            times.size - 1,
            m + SIMULATED_STEPS + int(np.ceil(self.hold / self.description.control_period)),
        )
        for j in range(m, last):
            t, dt = float(times[j]), float(times[j + 1] - times[j])
            q = self.track_step(theta, t, dt)
            inside = inside_intervals_along_arc(
                theta, q - theta, lambda f, t=t, dt=dt: self.position(t + f * dt), eps
            )
            slow = slow_intervals_along_arc(
                theta, q - theta, dt, lambda f, t=t, dt=dt: self.velocity(t + f * dt), self.v_max
            )
            done, since = held_capture(intersect(inside, slow), since, t, dt, self.hold)
            if done is not None:
                return done
            theta = q
        return np.inf

    def track_step(self, theta: FloatArray, t: float, dt: float) -> FloatArray:
        """The joint vector at the end of a step of the approach and the tracking: the end-effector
        ends ``X_T(t + dt)`` plus the relative position moved along the approach (`advance`)
        at ``approach_speeds`` of ``v_max``, the first of them at which the step's instantaneous
        relative speed stays within ``v_max`` (the exact one-step IK solution; where none is within
        one step, the reachable point nearest eq. 20's box)."""
        eps = self.description.capture_tolerance
        here, ahead = self.at(t), self.at(t + dt)
        miss = forward_kinematics(theta) - here
        q = theta
        for fraction in self.approach_speeds:
            aim = advance(miss, eps, fraction * float(self.v_max) * dt)
            solution = one_step_solution(self.description, theta, ahead + aim, dt)
            if solution is None:
                arm = self.description.arm
                reach = arm.joint_rate_limits * min(dt, self.description.control_period)
                lo = np.maximum(arm.joint_lower, theta - reach * (1.0 - 1e-9))
                hi = np.minimum(arm.joint_upper, theta + reach * (1.0 - 1e-9))
                start = nearest_in_box(theta[None], (ahead + aim)[None], lo[None], hi[None])
                solution = nearest_in_box_about(start, ahead, APPROACH_DEPTH * eps, eps, lo, hi)[0]
            q = solution
            slow = slow_intervals_along_arc(
                theta, q - theta, dt, lambda f: self.velocity(t + f * dt), self.v_max
            )
            if slow == [(0.0, 1.0)]:
                break
        return q


def one_step_solution(
    description: TaskDescription, theta: NDArray, goal: NDArray, dt: float
) -> FloatArray | None:
    """An IK solution of ``goal`` within joint limits and one step of ``dt`` s of ``theta`` (the
    one needing the least of a step, in the largest joint's share), or None."""
    arm = description.arm
    reach = arm.joint_rate_limits * min(dt, description.control_period)  # |action| <= 1
    solutions = distinct_solutions(goal)
    if solutions.shape[0] == 0:
        return None
    ok = within_limits(solutions, arm.joint_lower, arm.joint_upper) & np.all(
        np.abs(solutions - theta) <= reach * (1.0 - 1e-9), axis=1
    )
    if not np.any(ok):
        return None
    candidates = solutions[ok]
    scaled = (candidates - theta) / reach
    return candidates[int(np.argmin(np.max(np.abs(scaled), axis=1)))]


def distinct_solutions(goal: FloatArray) -> FloatArray:
    """The distinct IK solutions of one point ``goal`` (3,), rad, (K, 3) with K in {0, 2, 4}:
    `inverse_kinematics`'s without its NaN rows, rounded to 1e-15 rad, in lexicographic order
    (the order ties between equally good solutions are broken in)."""
    solutions = inverse_kinematics(goal)
    return np.unique(np.round(solutions[~np.isnan(solutions[:, 0])], 15), axis=0)


def approach_time(miss: FloatArray, eps: FloatArray, speed: float) -> float:
    """How long the approach from the relative position ``miss`` (X_E - X_T, m) takes to enter
    eq. 20's box at ``speed`` (m/s) (`advance`'s straight line), s."""
    if np.all(np.abs(miss) < eps):
        return 0.0
    inner = np.clip(miss, -APPROACH_DEPTH * eps, APPROACH_DEPTH * eps)
    lo, _ = inside_intervals(miss[None], inner[None], eps)
    return float(lo[0]) * float(np.linalg.norm(inner - miss)) / speed if lo[0] == lo[0] else np.inf


def advance(miss: FloatArray, eps: FloatArray, step: float) -> FloatArray:
    """The relative position ``step`` m further along the approach from ``miss`` (X_E - X_T, m):
    straight to the nearest point of eq. 20's box shrunk to APPROACH_DEPTH, then straight to the
    capture point."""
    inner = np.clip(miss, -APPROACH_DEPTH * eps, APPROACH_DEPTH * eps)
    here = miss
    for aim in (inner, np.zeros(3)):
        gap = aim - here
        length = float(np.linalg.norm(gap))
        if length > step:
            return here + gap * (step / length)
        here, step = aim, step - length
    return here


def nearest_in_box_about(
    starts: FloatArray,
    point: FloatArray,
    half: FloatArray,
    eps: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    depth: float = LANDING_DEPTH,
) -> FloatArray:
    """From each of ``starts`` (K, 3), a joint vector in the box [lo, hi] whose end-effector is
    near the box of half-widths ``half`` about ``point``, (K, 3): of the alternate projections'
    result (the point of that box nearest the end-effector, then the joint vector nearest that
    point) and the joint vector nearest the corner of eq. 20's box (``eps``, shrunk to
    ``depth``) on the end-effector's side (where the reachable set's edge is flat, the
    point of eq. 20's box deepest into it: reachable if any point of the box is), the one
    whose largest component of the miss, over ``eps``, is least."""
    k = starts.shape[0]
    points, lo_k, hi_k = np.tile(point, (k, 1)), np.tile(lo, (k, 1)), np.tile(hi, (k, 1))
    q = nearest_in_box(starts, points, lo_k, hi_k)
    for _ in range(PROJECTIONS):
        q = nearest_in_box(
            q, points + np.clip(forward_kinematics(q) - points, -half, half), lo_k, hi_k
        )
    miss = forward_kinematics(q) - points
    corner = nearest_in_box(q, points + depth * eps * np.sign(miss), lo_k, hi_k)
    depth = np.max(np.abs(miss) / eps, axis=1)
    corner_depth = np.max(np.abs(forward_kinematics(corner) - points) / eps, axis=1)
    return np.where((corner_depth < depth)[:, None], corner, q)
