"""The paper's lambda_max incremental inverse-kinematics controller (Dong & Zhu 2016, eqs. 13-19).

Every control period t_s:

1. predict the target one period ahead, ``X_T' = X^_T + Xdot^_T t_s`` (eq. 13);
2. aim the end-effector straight at it, ``n = (X_T' - X_E) / ||X_T' - X_E||`` (eq. 14);
3. map the direction to joint space, ``u = J^-1 n`` (eq. 16 with ``J^dagger = J^-1``, as the paper
   does once the workspace keeps J full rank);
4. take the largest scale every joint allows, ``lambda_max = min_i theta_dot_max_i / |u_i|``
   (eq. 18), so the binding joint runs exactly at its rate limit;
5. step ``dTheta = lambda_max u t_s`` (eq. 19).

Two additions, both documented and switchable:

* **Step cap** (``cap=True``, the default): ``lambda = min(lambda_max, ||X_T' - X_E|| / t_s)``. At
  lambda_max every step the end-effector overshoots the 1 mm capture ball and chatters around it;
  the cap makes the last step land on X_T' (to first order). ``cap=False`` is the paper exactly.
* **Near-singular fallback**: where ``|det J| < det_threshold`` (det J = l1 l2 r cos(theta3)
  vanishes at r = 0 and theta3 = +-90 deg) ``J^-1`` is replaced by the damped least-squares inverse
  ``J^T (J J^T + mu^2 I)^-1`` (Wampler 1986; Nakamura & Hanafusa 1986). Inside the published
  joint limits |det J| >= 5e-3 m^3, so the fallback never triggers there: the controller is the
  paper's.

X_E is computed from the observed joint angles by forward kinematics (eq. 8), so the controller's
X_E and J come from the same Theta.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agents.base import AnalyticController, safe_action
from capture_bench.sim.kinematics import forward_kinematics_point, jacobian, jacobian_determinant
from capture_bench.task.observation import TaskDescription

FloatArray = NDArray[np.float64]

DET_THRESHOLD = 1e-3  # |det J| below which J^-1 is replaced by DLS, m^3
DAMPING = 0.05  # mu of the DLS fallback, m


@dataclass(frozen=True)
class IncrementalStep:
    """One evaluation of eqs. 13-19.

    Attributes:
        increment: joint increment dTheta, rad, shape (3,).
        direction: unit vector n (eq. 14), global frame, shape (3,) (zeros if X_T' = X_E).
        joint_direction: u = J^-1 n (eq. 16), rad/s per (m/s), shape (3,).
        lambda_max: largest speed scale the rate limits allow (eq. 18), m/s (0 if undefined).
        speed: the scale actually used (lambda_max, or the cap), m/s.
        singular: whether the DLS fallback replaced J^-1.
    """

    increment: FloatArray
    direction: FloatArray
    joint_direction: FloatArray
    lambda_max: float
    speed: float
    singular: bool


def lambda_max_of(joint_direction: NDArray, joint_rate_limits: NDArray) -> FloatArray:
    """Largest lambda with -theta_dot_max_i <= lambda u_i <= theta_dot_max_i for every i (eq. 18).

    Args:
        joint_direction: u, shape (3,) or (N, 3).
        joint_rate_limits: theta_dot_max, rad/s, shape (3,).

    Returns:
        lambda_max, m/s per unit n, shape () or (N,); 0 where u is all zeros.
    """
    u = np.abs(np.asarray(joint_direction, dtype=float))
    if u.shape == (3,):  # one direction, every control step: Python floats, same arithmetic
        limits = [
            r / a for r, a in zip(np.asarray(joint_rate_limits).tolist(), u.tolist()) if a > 0
        ]
        lam_one = min(limits, default=0.0)
        return np.asarray(lam_one if math.isfinite(lam_one) else 0.0)
    rates = np.broadcast_to(np.asarray(joint_rate_limits, dtype=float), u.shape)
    per_joint = np.divide(rates, u, out=np.full(u.shape, np.inf), where=u > 0.0)
    lam = np.min(per_joint, axis=-1)
    return np.where(np.isfinite(lam), lam, 0.0)


def resolve_direction(
    theta: NDArray,
    direction: NDArray,
    det_threshold: float = DET_THRESHOLD,
    damping: float = DAMPING,
) -> tuple[FloatArray, bool]:
    """u = J^-1 n (eq. 16), with the DLS inverse where J is near-singular.

    Args:
        theta: joint angles, rad, shape (3,).
        direction: Cartesian direction(s) n, global frame, shape (3,) or (N, 3).
        det_threshold: |det J| (m^3) below which the DLS inverse is used.
        damping: DLS damping mu, m.

    Returns:
        (u with the shape of ``direction``, whether the fallback was used).
    """
    jac = jacobian(theta)
    n = np.asarray(direction, dtype=float)
    singular = bool(abs(jacobian_determinant(theta)) < det_threshold)
    if singular:
        # J^T (J J^T + mu^2 I)^-1 n: always defined, bounded by 1/(2 mu) per unit n.
        lhs = jac @ jac.T + damping**2 * np.eye(3)
        u = (jac.T @ np.linalg.solve(lhs, n.T)).T
    else:
        u = np.linalg.solve(jac, n.T).T
    return u, singular


def incremental_step(
    theta: NDArray,
    target_position: NDArray,
    target_velocity: NDArray,
    description: TaskDescription,
    cap: bool = True,
    det_threshold: float = DET_THRESHOLD,
    damping: float = DAMPING,
) -> IncrementalStep:
    """One step of the incremental IK law, eqs. 13-19.

    Args:
        theta: current joint angles Theta, rad, shape (3,).
        target_position: estimated capture point X^_T, global frame, m, shape (3,).
        target_velocity: estimated target velocity Xdot^_T, global frame, m/s, shape (3,).
        description: the task's public description (rate limits, nominal period t_s).
        cap: apply the step cap lambda = min(lambda_max, ||X_T' - X_E|| / t_s).
        det_threshold: |det J| (m^3) below which the DLS fallback is used.
        damping: DLS damping mu, m.

    Returns:
        The step and its intermediate quantities.
    """
    t_s = description.control_period
    rates = description.arm.joint_rate_limits
    theta = np.asarray(theta, dtype=float)
    x_e = forward_kinematics_point(theta)  # eq. 8 (the scalar twin: same numbers, faster)
    predicted = np.asarray(target_position) + np.asarray(target_velocity) * t_s  # eq. 13
    offset = predicted - x_e
    distance = float(np.linalg.norm(offset))
    zeros = np.zeros(3)
    if not np.isfinite(distance) or distance == 0.0:
        return IncrementalStep(zeros, zeros, zeros, 0.0, 0.0, False)
    n = offset / distance  # eq. 14
    u, singular = resolve_direction(theta, n, det_threshold, damping)  # eq. 16
    lam_max = float(lambda_max_of(u, rates))  # eq. 18
    speed = min(lam_max, distance / t_s) if cap else lam_max
    increment = speed * u * t_s  # eq. 19
    return IncrementalStep(increment, n, u, lam_max, speed, singular)


class IncrementalIK(AnalyticController):
    """The paper's lambda_max controller (eqs. 13-19) as an :class:`agents.protocol.Agent`.

    Args:
        description: the environment's public :class:`TaskDescription` (the only thing it knows).
        cap: step cap on (default) or the paper's uncapped eqs. 13-19 (``cap=False``).
        det_threshold: |det J| (m^3) below which the DLS fallback replaces J^-1.
        damping: DLS damping mu, m.
    """

    def __init__(
        self,
        description: TaskDescription,
        cap: bool = True,
        det_threshold: float = DET_THRESHOLD,
        damping: float = DAMPING,
    ) -> None:
        super().__init__(description)
        self.cap = cap
        self.det_threshold = det_threshold
        self.damping = damping
        self.last_step: IncrementalStep | None = None

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """Action for one observation (eqs. 13-19), shape (3,), float32, in [-1, 1]."""
        obs = self.decode(observation)
        step = incremental_step(
            obs.joint_angles,
            obs.target_position,
            obs.target_velocity,
            self.description,
            cap=self.cap,
            det_threshold=self.det_threshold,
            damping=self.damping,
        )
        self.last_step = step
        return safe_action(self.description.increment_to_action(step.increment))

    def reset(self) -> None:
        """Forget the last step's diagnostics."""
        self.last_step = None
