"""The privileged oracle: it knows the true target trajectory and attains the physical limit.

**Privileged.** Unlike every other agent it reads the world's ground truth through the
environment's privileged API (``env.unwrapped.physical_limit()``, ``true_target_position(t)``,
``time``, ``next_control_period``). It is not a controller anyone could deploy; it exists to show
that the per-episode lower bound on capture time (``capture_bench/task/physical_limit.py``) is
attainable, so ratios to the bound are meaningful. Label it "oracle (privileged)" wherever it
appears.

Plan, per episode:

1. *Go to the bound.* At the episode's first step it asks ``physical_limit()`` for ``(T, theta*)``:
   the earliest time ``T`` at which the true capture point has an IK solution ``theta*`` inside the
   box ``|theta_i - theta_i(0)| <= theta_dot_max_i t``. Each joint is driven straight toward
   ``theta*`` at up to its full rate, ``a = clip((theta* - theta) / (theta_dot_max t_s), -1, 1)``,
   so every joint is at ``theta*`` by time T.
2. *Close in one step.* Before each step it checks whether an IK solution (within joint limits) of
   the true target position at the *end* of the step, ``X_T(t + dt)``, is reachable in one step
   (dt: the step's real period, ``next_control_period``, which varies under ``jitter``); if so it
   commands exactly that, which captures at ``t + dt``. Because the bound's onset falls
   inside a control period, this is what makes the capture land within one period of T rather
   than the target drifting away from ``theta*`` while the arm waits there.
3. *Track (with a hold).* Where the scenario asks eq. 20 to hold for ``hold`` s, the bound is the
   arrival ``T`` plus ``hold``. From the step that ends at or after ``T`` (or once every joint
   is at ``theta*``), where no exact one-step solution exists, it moves to the joint vector
   within one step (and the joint limits) whose end-effector is nearest ``X_T(t + dt)``
   (``nearest_in_box`` of the bound's own search, started from ``theta*`` the first time),
   ``mode = "track"``, and never returns to ``theta*``: ``theta*`` is only within ``|epsilon|``
   of the capture point at ``T``, the bound's sphere, not yet inside eq. 20's cube. The exact
   one-step solution of 2. then keeps the end-effector on the capture point at every step's
   end. (Without a hold the episode ends at the entry, and the oracle goes on as before: 4.)
4. *Fallback.* If the bound is infinite (the target is never reachable within the horizon), or the
   plan is spent without a capture, it runs the paper's incremental IK step (eqs. 13-19, capped)
   on the true position one period ahead, ``X_T(t + t_s)``, and reports ``mode = "fallback"``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.agents.base import predict_each, safe_action
from capture_bench.agents.incremental_ik import incremental_step
from capture_bench.sim.kinematics import inverse_kinematics, within_limits
from capture_bench.task.observation import TaskDescription, decode_observation
from capture_bench.task.physical_limit import nearest_in_box


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

    def reset(self) -> None:
        """Forget the plan; the next ``predict`` asks the environment for the new bound."""
        self.theta_star = None
        self.bound_time = None
        self.hold = 0.0
        self.arrival = np.inf
        self.tracking = False
        self.mode = "plan"
        self._last_time = -np.inf

    def _plan(self) -> None:
        limit = self.world.physical_limit()
        self.bound_time = float(limit.time)
        self.hold = float(getattr(limit, "hold", 0.0))
        self.arrival = self.bound_time - self.hold  # when eq. 20 can first hold, s
        finite = np.isfinite(self.bound_time) and limit.theta is not None
        self.theta_star = np.asarray(limit.theta, dtype=float) if finite else None
        self.mode = "bound" if finite else "fallback"

    def _true_position(self, t: float) -> NDArray[np.float64]:
        return np.asarray(self.world.true_target_position(float(t)), dtype=float).reshape(3)

    def _one_step_solution(
        self, theta: NDArray, goal: NDArray, dt: float
    ) -> NDArray[np.float64] | None:
        """An IK solution of ``goal`` within joint limits and one step of ``dt`` s of ``theta``,
        or None."""
        arm = self.description.arm
        reach = arm.joint_rate_limits * min(dt, self.description.control_period)  # |action| <= 1
        solutions = inverse_kinematics(goal)
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

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """Action for one observation, shape (3,), float32, in [-1, 1]."""
        t = float(self.world.time)
        if self.bound_time is None or t < self._last_time:  # first step of a new episode
            self._plan()
        self._last_time = t
        desc = self.description
        theta = decode_observation(observation, desc.control_period).joint_angles
        dt = float(self.world.next_control_period)
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
        step = incremental_step(theta, goal, np.zeros(3), desc, cap=True)
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
