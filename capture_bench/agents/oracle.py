"""The privileged oracle: it knows the true target trajectory and attains the physical limit.

**Privileged.** Unlike every other agent it reads the world's ground truth through the
environment's privileged API (``env.unwrapped.physical_limit()``, ``true_target_position(t)``,
``time``, ``next_control_period``, and under the capture envelope ``plan``: the trajectory and
every step's period). It is not a controller anyone could deploy; it exists to show
that the per-episode lower bound on capture time (``capture_bench/task/physical_limit.py``) is
attainable, so ratios to the bound are meaningful. Label it "oracle (privileged)" wherever it
appears.

Plan, per episode, under the capture envelope (a scenario with ``capture.v_max``):

1. *The entry.* At the episode's first step it asks ``physical_limit()`` for the arrival T (the
   bound less the hold) and ``theta*``, and from T the earliest entry t_e from which the arm can
   be in the envelope for the hold (`held_arrivals`,
   the bound's own test: where the environment's bound is the envelope's, t_e is T).
2. *Land slow.* Joint rates are constant within a step, so an arm that arrives at full rate is
   still fast until the step ends, and the capture could start only a step later. Instead it
   picks a step end ``t_m`` and the joint vector ``theta_m`` of the box reachable by then whose
   end-effector is nearest eq. 20's box about ``X_T(t_m)`` (shrunk to ``LANDING_DEPTH``; alternate
   projections from ``theta*`` and from each IK solution, or the joint vector nearest the box's
   corner on the arm's side, whichever is deeper), drives every joint there at up to its
   full rate, ``mode = "bound"``, and from ``t_m`` on takes the approach-and-track steps of 3.
   Landing inside eq. 20's box, the stay starts at ``t_m``; landing just outside it one step
   earlier, the slow approach enters it within the next step. Of the ``LANDING_CANDIDATES`` step
   ends from the last one before t_e it keeps the one whose capture completes first, simulated
   with the rule's own tests (eq. 20's box and the speed bound along each step's arc,
   `held_capture`). Steps 2 and 3 are `EnvelopePlan`'s
   (``capture_bench/agents/envelope_plan.py``), given the true trajectory.
3. *Approach and track.* Each step ends the end-effector on ``X_T(t + dt)`` plus a relative
   position that moves at ``0.99 v_max`` straight to eq. 20's box shrunk to ``APPROACH_DEPTH``,
   then to the capture point: the exact one-step IK solution (within the joint limits), or where
   none is within one step, the reachable joint vector nearest that box. The step's relative
   velocity along its arc is checked with the rule's test
   (`slow_intervals_along_arc`); where it exceeds ``v_max``,
   the slower ``APPROACH_SPEEDS`` are tried, down to keeping the relative position
   (``mode = "track"``). If no landing captures in the simulation, it plays 4.-7. below.

Without a speed bound (``v_max`` null), or if the plan of 1.-3. finds no capture:

4. *Go to the bound.* It asks ``physical_limit()`` for ``(T, theta*)``: the earliest time ``T``
   at which the true capture point has an IK solution ``theta*`` inside the box
   ``|theta_i - theta_i(0)| <= theta_dot_max_i t``. Each joint is driven straight toward
   ``theta*`` at up to its full rate, ``a = clip((theta* - theta) / (theta_dot_max t_s), -1, 1)``,
   so every joint is at ``theta*`` by time T.
5. *Close in one step.* Before each step it checks whether an IK solution (within joint limits) of
   the true target position at the *end* of the step, ``X_T(t + dt)``, is reachable in one step
   (dt: the step's real period, ``next_control_period``, which varies under ``jitter``); if so it
   commands exactly that, which captures at ``t + dt``. Because the bound's onset falls
   inside a control period, this is what makes the capture land within one period of T rather
   than the target drifting away from ``theta*`` while the arm waits there.
6. *Track (with a hold).* Where the scenario asks eq. 20 to hold for ``hold`` s, the bound is the
   arrival ``T`` plus ``hold``. From the step that ends at or after ``T`` (or once every joint
   is at ``theta*``), where no exact one-step solution exists, it moves to the joint vector
   within one step (and the joint limits) whose end-effector is nearest ``X_T(t + dt)``
   (``nearest_in_box`` of the bound's own search, started from ``theta*`` the first time),
   ``mode = "track"``, and never returns to ``theta*``: ``theta*`` is only within ``|epsilon|``
   of the capture point at ``T``, the bound's sphere, not yet inside eq. 20's cube. The exact
   one-step solution of 5. then keeps the end-effector on the capture point at every step's
   end. (Without a hold the episode ends at the entry, and the oracle goes on as before: 7.)
7. *Fallback.* If the bound is infinite (the target is never reachable within the horizon), or the
   plan is spent without a capture, it runs the paper's incremental IK step (eqs. 13-19, capped)
   on the true position one period ahead, ``X_T(t + t_s)``, and reports ``mode = "fallback"``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.agents.base import predict_each, safe_action
from capture_bench.agents.envelope_plan import EnvelopePlan, one_step_solution
from capture_bench.agents.incremental_ik import incremental_steps
from capture_bench.task.observation import TaskDescription, decode_observation
from capture_bench.task.physical_limit import held_arrivals, nearest_in_box

FloatArray = NDArray[np.float64]


class Oracle:
    """Privileged agent that attains the physical-limit bound (see module docstring).

    Args:
        env: the environment (or a wrapper of it); the oracle reads ``env.unwrapped``'s privileged
            API and its public ``description``.
    """

    privileged = True
    label = "oracle (privileged)"

    def __init__(self, env: Any) -> None:
        self.world = env.unwrapped
        self.description: TaskDescription = self.world.description
        self.theta_star: NDArray[np.float64] | None = None
        self.bound_time: float | None = None
        self.hold = 0.0
        self.arrival = np.inf
        self.tracking = False
        self.mode = "plan"
        self._last_time = -np.inf
        self.v_max: float | None = None
        self.landing: tuple[float, FloatArray] | None = None  # (t_m, theta_m) under v_max

    def reset(self) -> None:
        """Forget the plan; the next ``predict`` asks the environment for the new bound."""
        self.theta_star = None
        self.bound_time = None
        self.hold = 0.0
        self.arrival = np.inf
        self.tracking = False
        self.mode = "plan"
        self._last_time = -np.inf
        self.v_max = None
        self.landing = None

    def _plan(self) -> None:
        limit = self.world.physical_limit()
        self.bound_time = float(limit.time)
        self.hold = float(getattr(limit, "hold", 0.0))
        self.arrival = self.bound_time - self.hold  # when eq. 20 can first hold, s
        finite = np.isfinite(self.bound_time) and limit.theta is not None
        self.theta_star = np.asarray(limit.theta, dtype=float) if finite else None
        self.mode = "bound" if finite else "fallback"
        self.v_max = _speed_bound(self.world)
        if self.v_max is not None and self.theta_star is not None:
            entry, theta = self._held_arrival(self.arrival, self.theta_star)
            if np.isfinite(entry):
                self.landing = self._landing(entry, theta)

    def _held_arrival(self, arrival: float, theta: FloatArray) -> tuple[float, FloatArray]:
        """The earliest entry at or after ``arrival`` from which the envelope can be held
        (`held_arrivals`; ``arrival`` itself where the
        environment's bound already is the envelope's), and a joint vector there."""
        plan = self.world.plan
        desc, arm = self.description, self.description.arm
        jitter = plan.scenario.control.period_jitter
        entries, thetas = held_arrivals(
            np.array([arrival]),
            theta[None],
            [plan.trajectory.position],
            [plan.trajectory.velocity],
            arm.home,
            arm.joint_rate_limits,
            arm.joint_lower,
            arm.joint_upper,
            desc.capture_tolerance,
            horizons=[plan.end()],
            period=desc.control_period,
            travel_times=[plan.travel_time if jitter else None],
            hold=self.hold,
            v_max=self.v_max,
        )
        return float(entries[0]), thetas[0]

    def _true_position(self, t: float) -> NDArray[np.float64]:
        return np.asarray(self.world.true_target_position(float(t)), dtype=float).reshape(3)

    def _one_step_solution(
        self, theta: NDArray, goal: NDArray, dt: float
    ) -> NDArray[np.float64] | None:
        """An IK solution of ``goal`` within joint limits and one step of ``dt`` s of ``theta``,
        or None (`one_step_solution`)."""
        return one_step_solution(self.description, theta, goal, dt)

    def _nearest_in_one_step(
        self, theta: NDArray, goal: NDArray, dt: float, start: NDArray
    ) -> NDArray[np.float64]:
        """The joint vector within one step of ``dt`` s of ``theta`` and the joint limits whose
        end-effector is nearest ``goal`` (local search from ``start`` clipped to that box)."""
        arm = self.description.arm
        reach = arm.joint_rate_limits * min(dt, self.description.control_period) * (1.0 - 1e-9)
        lo = np.maximum(arm.joint_lower, theta - reach)
        hi = np.minimum(arm.joint_upper, theta + reach)
        return nearest_in_box(start[None], goal[None], lo[None], hi[None])[0]

    def _envelope_plan(self) -> EnvelopePlan:
        """The landing and tracking of `EnvelopePlan` on the true trajectory (privileged)."""
        trajectory = self.world.plan.trajectory
        return EnvelopePlan(
            self.description, trajectory.position, trajectory.velocity, self.v_max, self.hold
        )

    def _landing(self, entry: float, theta_star: FloatArray) -> tuple[float, FloatArray] | None:
        """Under a speed bound: the step end ``t_m`` and the joint vector ``theta_m`` the arm
        goes to at full rate from home, after which the approach and the tracking complete the
        capture the earliest (`EnvelopePlan.landing` over the episode's own step ends); None if
        none of them captures."""
        plan = self.world.plan
        times, _ = plan.step_times()
        travel = plan.travel_time(times) if plan.scenario.control.period_jitter else times
        return self._envelope_plan().landing(
            entry, theta_star, self.description.arm.home, times, travel
        )

    def _track_step(self, theta: FloatArray, t: float, dt: float) -> FloatArray:
        """One step of the approach and the tracking (`EnvelopePlan.track_step`)."""
        return self._envelope_plan().track_step(theta, t, dt)

    def _envelope_action(self, theta: FloatArray, t: float, dt: float) -> NDArray[np.float32]:
        """Under a speed bound: full rate to ``theta_m`` by ``t_m``, then `_track_step`."""
        assert self.landing is not None
        t_m, theta_m = self.landing
        scale = self.description.arm.joint_rate_limits * self.description.control_period
        if t + dt <= t_m + 1e-9:
            self.mode = "bound"
            return safe_action((theta_m - theta) / scale)
        self.mode = "track"
        return safe_action((self._track_step(theta, t, dt) - theta) / scale)

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """Action for one observation, shape (3,), float32, in [-1, 1]."""
        t = float(self.world.time)
        if self.bound_time is None or t < self._last_time:  # first step of a new episode
            self._plan()
        self._last_time = t
        desc = self.description
        theta = decode_observation(observation, desc.control_period).joint_angles
        dt = float(self.world.next_control_period)
        if self.landing is not None:
            return self._envelope_action(theta, t, dt)
        goal = self._true_position(t + dt)
        scale = desc.arm.joint_rate_limits * desc.control_period
        direct = self._one_step_solution(theta, goal, dt)
        if direct is not None:  # capture at the end of this step
            return safe_action((direct - theta) / scale)
        star = self.theta_star
        away = star is not None and bool(np.any(np.abs(star - theta) > 1e-6))
        if (
            star is not None
            and self.hold > 0.0
            and (self.tracking or not away or t + dt >= self.arrival)
        ):
            start = theta if self.tracking else star
            self.tracking = True  # from now on: track
            self.mode = "track"
            return safe_action((self._nearest_in_one_step(theta, goal, dt, start) - theta) / scale)
        if star is not None and away:
            return safe_action((star - theta) / scale)  # full rate toward theta*
        self.mode = "fallback"
        step = incremental_steps(theta[None], goal[None], np.zeros((1, 3)), desc, cap=True).row(0)
        return safe_action(desc.increment_to_action(step.increment))

    def predict(
        self,
        observation: NDArray,
        state: Any = None,
        episode_start: NDArray | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[np.float32], Any]:
        """SB3-style predict: ``(action, state)``; ``episode_start`` true forces a new plan."""
        if episode_start is not None and bool(np.any(episode_start)):
            self.reset()
        return predict_each(self.act, observation), state


def _speed_bound(world: Any) -> float | None:
    """The scenario's ``capture.v_max`` (m/s; None: no speed bound, or a world without a plan)."""
    plan = getattr(world, "plan", None)
    capture = getattr(getattr(plan, "scenario", None), "capture", None)
    v_max = getattr(capture, "v_max", None)
    return None if v_max is None else float(v_max)
