"""The physical limit of an episode: a lower bound on any agent's capture time (DESIGN.md).

Joints are independent velocity-limited integrators, so the joint vectors reachable by time t form
the box ``|theta_i - theta_i(0)| <= theta_dot_max_i t`` intersected with the joint limits. The
earliest time at which the true capture point X_T(t) has an inverse-kinematics solution inside
that box (within the capture tolerance epsilon, component-wise as in eq. 20) bounds every agent's
capture time from below.

How it is computed:

1. On the grid ``t_k = k * period`` up to the horizon, every closed-form IK solution of X_T(t_k)
   is tested against the box (exact). Where none lies inside but one lies within
   ``NEAR_BOX`` rad of it, the tolerance is used: from the solution clipped to the box,
   :func:`nearest_in_box` (active-set projected Gauss-Newton) finds the box's joint vector whose
   end-effector is nearest X_T, and the point counts as feasible when that distance is below
   ``|epsilon|`` (the radius of the sphere around eq. 20's tolerance cube). Using the sphere, not
   the cube, keeps the bound a *lower* bound: anything eq. 20 accepts is inside the sphere. (Inside
   the joint limits the end-effector moves at least ~0.07 m per rad of any joint, so a solution
   further than ``NEAR_BOX`` = 0.1 rad outside the box is > 1.7 mm from anything near it.)
2. Between the last infeasible and the first feasible grid time, the interval is searched
   ``REFINE_PASSES`` times with ``REFINE`` evenly spaced times, which finds the onset to
   ``period / REFINE**REFINE_PASSES`` (12 microseconds at t_s = 0.05 s). The
   bound is exact to well below the control period, assuming feasibility does not switch on and
   off again inside one period (the box grows monotonically; the target moves mm per period).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from capture_bench.kinematics import forward_kinematics, inverse_kinematics_batch, jacobian

FloatArray = NDArray[np.float64]
NEWTON_STEPS = 10
NEAR_BOX = 0.1  # rad
REFINE = 64
REFINE_PASSES = 2
CHUNK = 32


@dataclass(frozen=True)
class PhysicalLimit:
    """The episode's bound.

    Attributes:
        time: earliest feasible capture time, s; ``inf`` if the target is never reachable in time.
        theta: a joint vector, rad, (3,), whose end-effector is within ``|epsilon|`` of the capture
            point at ``time`` (None if inf).
    """

    time: float
    theta: FloatArray | None


def feasible_solutions(
    targets: FloatArray,
    times: FloatArray,
    theta0: FloatArray,
    joint_rate_limits: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    tolerance: FloatArray,
) -> tuple[NDArray[np.bool_], FloatArray]:
    """For each time, whether the target is reachable inside the box, and a joint vector that does.

    Args:
        targets: capture point X_T(t), global, m, (N, 3).
        times: how long the joints have moved at full rate by each t, s, (N,) (t itself when
            every step lasts t_s).
        theta0: joint angles at t = 0, rad, (3,).
        joint_rate_limits: theta_dot_max, rad/s, (3,).
        lower, upper: joint limits, rad, (3,).
        tolerance: epsilon, m, (3,).

    Returns:
        ``(feasible (N,), theta (N, 3))``; theta rows are meaningful where feasible.
    """
    n = targets.shape[0]
    box_lo = np.maximum(lower, theta0 - np.outer(times, joint_rate_limits))  # (N, 3)
    box_hi = np.minimum(upper, theta0 + np.outer(times, joint_rate_limits))
    solutions = inverse_kinematics_batch(targets)  # (N, 4, 3), NaN where none
    inside = np.all((solutions >= box_lo[:, None]) & (solutions <= box_hi[:, None]), axis=2)
    feasible = inside.any(axis=1)
    theta = np.zeros((n, 3))
    first = np.argmax(inside, axis=1)
    theta[feasible] = solutions[feasible, first[feasible]]
    excess = np.maximum(box_lo[:, None] - solutions, solutions - box_hi[:, None]).max(axis=2)
    near = ~feasible[:, None] & (excess < NEAR_BOX)  # (N, 4); False where NaN
    if np.any(near):
        rows, cols = np.nonzero(near)
        goal = targets[rows]
        q = nearest_in_box(solutions[rows, cols], goal, box_lo[rows], box_hi[rows])
        close = np.linalg.norm(forward_kinematics(q) - goal, axis=1) < np.linalg.norm(tolerance)
        feasible[rows[close]] = True
        theta[rows[close]] = q[close]
    return feasible, theta


def nearest_in_box(
    start: FloatArray,
    goal: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    iterations: int = NEWTON_STEPS,
) -> FloatArray:
    """Joint vectors in the box [lo, hi] whose end-effector is nearest ``goal`` (local search).

    Active-set projected Gauss-Newton on ``||f(theta) - goal||^2``: a joint on a bound whose
    gradient points out of the box is held there, the others take the least-squares step.

    Args:
        start: initial joint vectors, rad, (M, 3).
        goal: target points, global, m, (M, 3).
        lo, hi: box bounds, rad, (M, 3).
    """
    q = np.clip(start, lo, hi)
    for _ in range(iterations):
        residual = goal - forward_kinematics(q)  # (M, 3)
        jac = jacobian(q)  # (M, 3, 3)
        ascent = np.einsum("mij,mi->mj", jac, residual)  # J^T r: where moving theta helps
        held = ((q <= lo) & (ascent < 0.0)) | ((q >= hi) & (ascent > 0.0))
        # Least squares over the free joints: (Jf^T Jf + diag(held)) step = Jf^T r, where Jf is
        # J with the held joints' columns zeroed (their step is then exactly 0).
        free_jac = jac * ~held[:, None, :]
        normal = np.einsum("mki,mkj->mij", free_jac, free_jac) + held[:, :, None] * np.eye(3)
        rhs = np.einsum("mij,mi->mj", free_jac, residual)
        step = np.linalg.solve(normal, rhs[..., None])[..., 0]
        q = np.clip(q + step, lo, hi)
        if np.max(np.abs(step)) < 1e-10:
            break
    return q


def physical_limit(
    target_position: Callable[[FloatArray], FloatArray],
    theta0: FloatArray,
    joint_rate_limits: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    tolerance: FloatArray,
    horizon: float,
    period: float,
    travel_time: Callable[[FloatArray], FloatArray] | None = None,
) -> PhysicalLimit:
    """The earliest time the true capture point can be reached (see module docstring).

    Args:
        target_position: X_T(t) for times of shape (N,), returning (N, 3), global, m.
        theta0: joint angles at t = 0, rad, (3,).
        joint_rate_limits: theta_dot_max, rad/s, (3,).
        lower, upper: joint limits, rad, (3,).
        tolerance: epsilon, m, (3,).
        horizon: episode limit, s; no bound beyond it.
        period: grid spacing (the nominal control period t_s), s.
        travel_time: for times t (N,), how long each joint can have moved at its full rate by
            t, s (N,); default t itself. When the real control period varies, a step longer than
            t_s moves a joint at most theta_dot_max t_s (the action's range), so less than t.
    """
    args = (
        np.asarray(theta0, float),
        np.asarray(joint_rate_limits, float),
        np.asarray(lower, float),
        np.asarray(upper, float),
        np.asarray(tolerance, float),
    )

    def check(times: FloatArray) -> tuple[NDArray[np.bool_], FloatArray]:
        travel = times if travel_time is None else travel_time(times)
        return feasible_solutions(target_position(times), travel, *args)

    n_grid = int(np.floor(horizon / period + 1e-9)) + 1
    for start in range(0, n_grid, CHUNK):
        times = np.arange(start, min(start + CHUNK, n_grid), dtype=np.float64) * period
        ok, theta = check(times)
        if not ok.any():
            continue
        k = int(np.argmax(ok))
        if start + k == 0:
            return PhysicalLimit(0.0, theta[0])
        t_lo, t_hi, best = times[k] - period, times[k], theta[k]
        for _ in range(REFINE_PASSES):
            fine = np.linspace(t_lo, t_hi, REFINE + 1)[1:]
            ok_fine, theta_fine = check(fine)
            j = int(np.argmax(ok_fine))  # the last entry (t_hi) is known to be feasible
            if ok_fine[j]:
                t_lo, t_hi, best = (fine[j - 1] if j else t_lo), fine[j], theta_fine[j]
        return PhysicalLimit(float(t_hi), best)
    return PhysicalLimit(float("inf"), None)
