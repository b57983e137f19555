"""The oracle's plan on the estimate: land slow and track, from the observation alone.

`PlannedIntercept` plans a capture as the privileged oracle (``capture_bench/agents/oracle.py``)
does, but on the trajectory the estimate implies instead of the true one:

* **What it knows**: the observation (the estimate X^_T, Xdot^_T, the arm's joint angles, the last
  real period) and the task's public description (the arm, t_s, epsilon), plus the capture
  envelope's ``v_max`` and hold (by default the ranked scenarios', ``CaptureConfig``'s defaults).
  It never reads the environment.
* **What it assumes**: the capture point moves at the estimated velocity from the estimated
  position, ``X_T(tau) = X^_T + Xdot^_T tau`` (a `LinearDrift` from now, tau in s from the current
  step: `LinearDrift`'s position and velocity, a `TargetTrajectory` without spin or offset), and
  every step lasts the nominal t_s.

On that trajectory, with time counted from the current step and the reachable box about the
current joint angles, it takes the physical limit's arrival and entry into the envelope
(`physical_limits`, `held_arrivals`), and the oracle's landing (full rate to ``theta_m`` by the
step end ``t_m``: `EnvelopePlan.landing`, over ``candidates`` step ends) and approach-and-track
steps (`EnvelopePlan.track_step`, on the newest estimate's trajectory at every step after the
landing). Its approach is slower and its landing deeper into eq. 20's box than the oracle's
(``approach_speeds``, ``landing_depth``): the estimate's velocity error adds to the relative
speed the envelope bounds, and its position error moves the box.

A plan is kept, and checked at every step:

* the joints moved further than any action moves them in one step (a new episode began), or the
  landing is spent and the end-effector is further than ``track_range`` from X^_T: it plans
  again;
* ``theta_m`` is out of reach by ``t_m`` (another agent acted, or a step was short): the landing
  pose is adjusted (`EnvelopePlan.landing_pose` for where the estimate puts the capture point at
  ``t_m``, else one step later), and where neither lands inside eq. 20's box shrunk to
  ``ADJUST_DEPTH`` it plans again;
* the estimate now puts the capture point at ``t_m`` more than ``replan_fraction`` of epsilon
  from where the plan did: within ``NEAR_LANDING`` s of the landing the pose is adjusted for the
  same ``t_m`` (else it plans again); further away it plans again, at most every
  ``replan_steps`` steps (a new ``t_m`` matters there: early estimates can be far off).

With no valid estimate (the observation then carries X_E as the target and zero velocity) or no
capture within ``horizon``, it takes the paper's incremental IK step (eqs. 13-19, capped), as
``incremental_ik`` does, and tries to plan again after ``replan_steps`` steps.

The plan of a row is kept between calls: ``predict`` with ``episode_start`` true, or ``reset``,
forgets it, and a batch of N observations keeps N plans (row i is episode i). A row whose
observation has not changed since the last call (an ended episode's, in a batch) gets the same
action again. It is therefore not a function of the observation alone (not a residual base),
unless built with ``keep_plans=False``, which plans every row from scratch at every call.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.agents.base import AnalyticController, safe_action
from capture_bench.agents.envelope_plan import EnvelopePlan
from capture_bench.agents.incremental_ik import incremental_steps
from capture_bench.sim.kinematics import forward_kinematics
from capture_bench.sim.target_motion import LinearDrift
from capture_bench.task.observation import OBSERVATION_SIZE, TaskDescription, estimate_seen
from capture_bench.task.physical_limit import physical_limits
from capture_bench.task.scenarios import CaptureConfig

FloatArray = NDArray[np.float64]
#: The envelope it plans for when not told: the ranked scenarios' (every one of them).
DEFAULT_V_MAX = float(CaptureConfig().v_max)  # type: ignore[arg-type]
DEFAULT_HOLD = float(CaptureConfig().hold)
#: How far ahead it looks for a capture, s (the default episode limit).
HORIZON = 10.0
#: A change of the predicted landing point, in epsilon, that makes it plan again.
REPLAN_FRACTION = 0.5
#: The approach's relative speeds, fractions of v_max: slower than the oracle's, since the
#: estimate's velocity error adds to the relative speed the envelope bounds.
APPROACH_SPEEDS = (0.8, 0.6, 0.3, 0.0)
#: The landing aims deeper into eq. 20's box than the oracle's, since the estimate's position
#: error moves the box.
LANDING_DEPTH = 0.6
#: Step ends the landing tries (the oracle's six cost three times as much and did no better).
LANDING_CANDIDATES = 2
#: Steps between two plans of a landing more than ``NEAR_LANDING`` s away.
REPLAN_STEPS = 5
#: Time before the landing within which a moved estimate is planned again at once, s.
NEAR_LANDING = 0.25
#: An adjusted landing must end inside eq. 20's box shrunk to this fraction, else it plans again.
ADJUST_DEPTH = 0.8
#: Relative distance beyond which a spent landing is planned again, m.
TRACK_RANGE = 0.03
#: Slack of the reach tests, rad.
SLACK = 1e-6


@dataclass
class _RowPlan:
    """One row's plan: the landing (``t_m`` s after the plan, ``theta_m``) and where the estimate
    put the capture point then (``goal``), the time and steps since the plan (or its last
    adjustment), the joint angles before the last action, and the last observation and
    action; ``fallback``: no capture found, the incremental IK step until it plans again."""

    t_m: float
    theta_m: FloatArray
    goal: FloatArray
    elapsed: float = 0.0
    steps: int = 0
    before: FloatArray | None = None
    observation: NDArray | None = None
    action: FloatArray | None = None
    fallback: bool = False


class PlannedIntercept(AnalyticController):
    """The oracle's landing and tracking on the estimate's constant-velocity trajectory
    (module docstring): non-privileged.

    Args:
        description: the environment's public description.
        v_max: the capture envelope's speed bound, m/s.
        hold: the capture envelope's hold, s.
        horizon: how far ahead it looks for a capture, s.
        replan_fraction: the change of the predicted landing point, in epsilon, that makes it
            plan again.
        replan_steps: the steps between two plans of a landing more than ``NEAR_LANDING`` s
            away.
        track_range: the relative distance beyond which a spent landing is planned again, m.
        approach_speeds: the approach's relative speeds, fractions of ``v_max``.
        landing_depth: the landing aims at eq. 20's box shrunk to this fraction of epsilon.
        candidates: how many step ends the landing tries (`EnvelopePlan.landing`).
        keep_plans: False plans every row from scratch at every call, so that the action is a
            function of the observation alone (a teacher's labels on states another policy
            visits, at several times the cost per step).
    """

    def __init__(
        self,
        description: TaskDescription,
        v_max: float = DEFAULT_V_MAX,
        hold: float = DEFAULT_HOLD,
        horizon: float = HORIZON,
        replan_fraction: float = REPLAN_FRACTION,
        replan_steps: int = REPLAN_STEPS,
        track_range: float = TRACK_RANGE,
        approach_speeds: tuple[float, ...] = APPROACH_SPEEDS,
        landing_depth: float = LANDING_DEPTH,
        candidates: int = LANDING_CANDIDATES,
        keep_plans: bool = True,
    ) -> None:
        super().__init__(description)
        self.keep_plans = bool(keep_plans)
        self.v_max, self.hold, self.horizon = float(v_max), float(hold), float(horizon)
        self.replan_fraction, self.track_range = float(replan_fraction), float(track_range)
        self.approach_speeds = tuple(approach_speeds)
        self.landing_depth = float(landing_depth)
        self.replan_steps, self.candidates = int(replan_steps), int(candidates)
        t_s = description.control_period
        self.times = t_s * np.arange(int(math.ceil(self.horizon / t_s)) + 1)
        self.plans: list[_RowPlan | None] = []
        #: how many plans it has made since built (diagnostics)
        self.planned = 0

    def reset(self) -> None:
        """Forget every row's plan."""
        super().reset()
        self.plans = []

    def predict(
        self,
        observation: NDArray,
        state: Any = None,
        episode_start: NDArray | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[np.float32], Any]:
        """`AnalyticController.predict`, the rows whose ``episode_start`` is true forgetting
        their plans first."""
        if episode_start is not None:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            for i in np.flatnonzero(starts).tolist():
                if i < len(self.plans):
                    self.plans[i] = None
        return super().predict(observation, state, episode_start, deterministic)

    def act_batch(self, observations: NDArray) -> NDArray[np.float32]:
        """Actions for N observations, (N, 16) -> (N, 3), float32, in [-1, 1]; row i keeps
        its plan between calls."""
        rows = np.asarray(observations).reshape(-1, OBSERVATION_SIZE)
        obs = self.decode(rows)
        n = obs.joint_angles.shape[0]
        if len(self.plans) != n or not self.keep_plans:
            self.plans = [None] * n
        actions = np.zeros((n, 3))
        theta, position, velocity = obs.joint_angles, obs.target_position, obs.target_velocity
        valid = estimate_seen(obs)
        period = np.broadcast_to(np.asarray(obs.last_period, dtype=float), (n,))
        fallback = []
        for i in range(n):
            if not valid[i]:
                self.plans[i] = None
                fallback.append(i)
                continue
            plan = self.plans[i]
            if plan is not None and np.array_equal(plan.observation, rows[i]):
                actions[i] = plan.action  # the same observation again: the same action
                continue
            step = self._act_row(i, theta[i], position[i], velocity[i], float(period[i]))
            if step is None:
                fallback.append(i)
            else:
                actions[i] = step
                plan = self.plans[i]
                assert plan is not None
                plan.observation, plan.action = rows[i], step
        if fallback:
            idx = np.array(fallback)
            step = incremental_steps(theta[idx], position[idx], velocity[idx], self.description)
            actions[idx] = self.description.increment_to_action(step.increment)
        return safe_action(actions)

    def _act_row(
        self, i: int, theta: FloatArray, position: FloatArray, velocity: FloatArray, dt: float
    ) -> FloatArray | None:
        """Row i's action, or None for the incremental IK step."""
        plan = self.plans[i]
        if plan is not None:
            plan.elapsed += dt
            plan.steps += 1
            if self._lost(plan, theta, position):
                plan = None
            elif self._late(plan, theta):
                plan = self._adjusted(plan, theta, position, velocity, steps=2)
            elif self._goal_moved(plan, position, velocity, near=True):
                plan = self._adjusted(plan, theta, position, velocity, steps=1)
            elif self._goal_moved(plan, position, velocity, near=False):
                plan = None
        if plan is not None and plan.fallback and plan.steps >= self.replan_steps:
            plan = None  # try again
        if plan is None:
            plan = self._plan(theta, position, velocity)
        self.plans[i] = plan
        if plan.fallback:
            return None
        t_s = self.description.control_period
        scale = self.description.arm.joint_rate_limits * t_s
        if plan.elapsed + t_s <= plan.t_m + 1e-9:  # land: full rate to theta_m by t_m
            move = np.clip((plan.theta_m - theta) / scale, -1.0, 1.0)
        else:  # approach and track on the newest estimate
            q = self._envelope(position, velocity).track_step(theta, 0.0, t_s)
            move = np.clip((q - theta) / scale, -1.0, 1.0)
        plan.before = theta
        return move

    def _lost(self, plan: _RowPlan, theta: FloatArray, position: FloatArray) -> bool:
        """Whether ``plan`` must be made again: the joints moved further than one step can move
        them (a new episode began), or the landing is spent and the end-effector is further
        than ``track_range`` from X^_T."""
        step = self.description.arm.joint_rate_limits * self.description.control_period
        if plan.before is not None and np.any(np.abs(theta - plan.before) > step + SLACK):
            return True
        if plan.fallback or plan.t_m - plan.elapsed > -1e-9:
            return False
        return bool(np.linalg.norm(forward_kinematics(theta) - position) > self.track_range)

    def _late(self, plan: _RowPlan, theta: FloatArray) -> bool:
        """Whether the landing is to come and ``theta_m`` is out of reach by ``t_m`` (another
        agent acted, or a step was short)."""
        remaining = plan.t_m - plan.elapsed
        if plan.fallback or remaining <= -1e-9:
            return False
        reach = self.description.arm.joint_rate_limits * max(remaining, 0.0)
        return bool(np.any(np.abs(plan.theta_m - theta) > reach + SLACK))

    def _goal_moved(
        self, plan: _RowPlan, position: FloatArray, velocity: FloatArray, near: bool
    ) -> bool:
        """Whether the landing is to come, within ``NEAR_LANDING`` s (``near``) or further
        (asked every ``replan_steps`` steps), and the estimate now puts the capture point at
        ``t_m`` more than ``replan_fraction`` of epsilon from ``goal`` in some component."""
        remaining = plan.t_m - plan.elapsed
        if plan.fallback or remaining <= -1e-9 or near != (remaining <= NEAR_LANDING):
            return False
        if not near and plan.steps < self.replan_steps:
            return False
        eps = self.description.capture_tolerance
        now = position + velocity * remaining
        return bool(np.any(np.abs(now - plan.goal) > self.replan_fraction * eps))

    def _adjusted(
        self,
        plan: _RowPlan,
        theta: FloatArray,
        position: FloatArray,
        velocity: FloatArray,
        steps: int,
    ) -> _RowPlan | None:
        """The landing at ``t_m`` or, with ``steps`` 2, where that fails one step later: the
        landing pose for where the estimate now puts the capture point then
        (`EnvelopePlan.landing_pose` in the box reachable by then), the first inside eq. 20's
        box about it shrunk to ``ADJUST_DEPTH``; None where none is."""
        arm, eps = self.description.arm, self.description.capture_tolerance
        envelope = self._envelope(position, velocity)
        for later in self.description.control_period * np.arange(steps):
            remaining = max(plan.t_m - plan.elapsed, 0.0) + later
            goal = position + velocity * remaining
            reach = arm.joint_rate_limits * remaining
            lo = np.maximum(arm.joint_lower, theta - reach)
            hi = np.minimum(arm.joint_upper, theta + reach)
            theta_m = envelope.landing_pose(goal, plan.theta_m, lo, hi)
            if np.all(np.abs(forward_kinematics(theta_m) - goal) <= ADJUST_DEPTH * eps):
                return _RowPlan(remaining, theta_m, goal, before=plan.before)
        return None

    def _envelope(self, position: FloatArray, velocity: FloatArray) -> EnvelopePlan:
        """`EnvelopePlan` on the estimate's trajectory, time from now."""
        drift = LinearDrift(position.copy(), velocity.copy())  # the capture point itself
        return EnvelopePlan(
            self.description,
            drift.position,
            drift.velocity_at,
            self.v_max,
            self.hold,
            self.approach_speeds,
            self.landing_depth,
            self.candidates,
        )

    def _plan(self, theta: FloatArray, position: FloatArray, velocity: FloatArray) -> _RowPlan:
        """The landing on the estimate's trajectory from ``theta`` now; where it finds no capture,
        a plan to take the incremental IK step (``fallback``) until it tries again."""
        self.planned += 1
        desc, arm = self.description, self.description.arm
        envelope = self._envelope(position, velocity)
        (limit,) = physical_limits(
            [envelope.position],
            theta,
            arm.joint_rate_limits,
            arm.joint_lower,
            arm.joint_upper,
            desc.capture_tolerance,
            horizons=[self.horizon],
            period=desc.control_period,
            hold=self.hold,
            v_max=self.v_max,
            target_velocities=[envelope.velocity],
        )
        none = _RowPlan(np.nan, theta, position, fallback=True)
        if not np.isfinite(limit.time) or limit.theta is None:
            return none
        landing = envelope.landing(limit.arrival, limit.theta, theta, self.times, self.times)
        if landing is None:
            return none
        t_m, theta_m = landing
        return _RowPlan(t_m, theta_m, position + velocity * t_m)
