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
* **Follow-through** (``follow_through=m``, default 0; the ``incremental_ik_through`` agent:
  `FOLLOW_THROUGH`): the cap aims m past X_T' along n,
  ``lambda = min(lambda_max, (||X_T' - X_E|| + m) / t_s)``, so the last step's arc sweeps through
  the capture point instead of stopping on it, where first-order and estimate errors leave it
  just outside a 1 mm ball for a few periods; with m below a scenario's tolerance the arm then
  stays within it, so a capture that must hold still holds.
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
from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.agents.base import AnalyticController, safe_action
from capture_bench.sim.kinematics import forward_kinematics, jacobian, jacobian_determinant
from capture_bench.task.observation import TaskDescription

FloatArray = NDArray[np.float64]

DET_THRESHOLD = 1e-3  # |det J| below which J^-1 is replaced by DLS, m^3
DAMPING = 0.05  # mu of the DLS fallback, m
#: The ``incremental_ik_through`` agent's follow-through m, m: chosen on the first 100 validation
#: seeds of each default scenario (1, 2 and 4 mm: 779, 779 and 777 of 800 captured, mean median
#: ratio to the physical limit 1.19, 1.16 and 1.17; incremental_ik 778 and 1.26), below grasp's
#: 5 mm tolerance so that a hold still holds. Measured by docs/results/generalist.md's command.
FOLLOW_THROUGH = 0.002


@dataclass(frozen=True)
class IncrementalStep:
    """One evaluation of eqs. 13-19, for one episode or a batch of N (leading axis N).

    Attributes:
        increment: joint increment dTheta, rad, shape (3,) or (N, 3).
        direction: unit vector n (eq. 14), global frame, shape (3,) or (N, 3) (zeros where
            X_T' = X_E).
        joint_direction: u = J^-1 n (eq. 16), rad/s per (m/s), shape (3,) or (N, 3).
        lambda_max: largest speed scale the rate limits allow (eq. 18), m/s (0 where undefined):
            a float, or shape (N,).
        speed: the scale actually used (lambda_max, or the cap), m/s: a float, or shape (N,).
        singular: whether the DLS fallback replaced J^-1: a bool, or shape (N,).
    """

    increment: FloatArray
    direction: FloatArray
    joint_direction: FloatArray
    lambda_max: Any
    speed: Any
    singular: Any

    def row(self, i: int) -> IncrementalStep:
        """Episode ``i`` of a batched step, with scalar ``lambda_max``, ``speed``, ``singular``."""
        return IncrementalStep(
            self.increment[i],
            self.direction[i],
            self.joint_direction[i],
            float(self.lambda_max[i]),
            float(self.speed[i]),
            bool(self.singular[i]),
        )


def row_norms(vectors: NDArray) -> FloatArray:
    """Euclidean norm of each row, shape (..., 3) -> (...): ``sqrt(v . v)`` through the BLAS dot
    that ``np.linalg.norm`` uses for one vector, so a row's norm does not depend on the batch."""
    v = np.asarray(vectors, dtype=float)
    return np.sqrt(np.matmul(v[..., None, :], v[..., :, None])[..., 0, 0])


def lambda_max_of(joint_direction: NDArray, joint_rate_limits: NDArray) -> FloatArray:
    """Largest lambda with -theta_dot_max_i <= lambda u_i <= theta_dot_max_i for every i (eq. 18).

    Args:
        joint_direction: u, shape (..., 3).
        joint_rate_limits: theta_dot_max, rad/s, shape (3,).

    Returns:
        lambda_max, m/s per unit n, shape (...); 0 where u is all zeros.
    """
    u = np.abs(np.asarray(joint_direction, dtype=float))
    rates = np.asarray(joint_rate_limits, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        per_joint = np.where(u > 0.0, rates / u, np.inf)  # inf where u_i is 0 (or NaN)
    # the least of the three, joint by joint (a minimum rounds nothing)
    lam = np.minimum(np.minimum(per_joint[..., 0], per_joint[..., 1]), per_joint[..., 2])
    return np.where(np.isfinite(lam), lam, 0.0)


def resolve_direction(
    theta: NDArray,
    direction: NDArray,
    det_threshold: float = DET_THRESHOLD,
    damping: float = DAMPING,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """u = J^-1 n (eq. 16), with the DLS inverse where J is near-singular, episode by episode.

    Args:
        theta: joint angles, rad, shape (N, 3).
        direction: Cartesian directions n, global frame, shape (N, 3), or (N, S, 3) for S
            directions per episode (each episode's J applies to all of its S).
        det_threshold: |det J| (m^3) below which the DLS inverse is used.
        damping: DLS damping mu, m.

    Returns:
        (u with the shape of ``direction``, whether the fallback was used, shape (N,)).
    """
    jac = jacobian(theta)  # (N, 3, 3)
    n = np.asarray(direction, dtype=float)
    rhs = n[..., None] if n.ndim == 2 else np.swapaxes(n, 1, 2)  # (N, 3, 1) or (N, 3, S)
    singular = np.abs(jacobian_determinant(theta)) < det_threshold
    u = np.empty(rhs.shape)
    regular = ~singular
    if regular.any():
        u[regular] = np.linalg.solve(jac[regular], rhs[regular])
    if singular.any():
        # J^T (J J^T + mu^2 I)^-1 n: always defined, bounded by 1/(2 mu) per unit n.
        j = jac[singular]
        lhs = j @ np.swapaxes(j, 1, 2) + damping**2 * np.eye(3)
        u[singular] = np.swapaxes(j, 1, 2) @ np.linalg.solve(lhs, rhs[singular])
    return (u[..., 0] if n.ndim == 2 else np.swapaxes(u, 1, 2)), singular


def incremental_steps(
    theta: NDArray,
    target_position: NDArray,
    target_velocity: NDArray,
    description: TaskDescription,
    cap: bool = True,
    det_threshold: float = DET_THRESHOLD,
    damping: float = DAMPING,
    follow_through: float = 0.0,
) -> IncrementalStep:
    """One step of the incremental IK law, eqs. 13-19, for N episodes at once.

    Each row is computed as it would be alone (no arithmetic mixes rows), so an episode's step
    does not depend on the batch it is in.

    Args:
        theta: current joint angles Theta, rad, shape (N, 3).
        target_position: estimated capture points X^_T, global frame, m, shape (N, 3).
        target_velocity: estimated target velocities Xdot^_T, global frame, m/s, shape (N, 3).
        description: the task's public description (rate limits, nominal period t_s).
        cap: apply the step cap lambda = min(lambda_max, (||X_T' - X_E|| + follow_through) / t_s).
        det_threshold: |det J| (m^3) below which the DLS fallback is used.
        damping: DLS damping mu, m.
        follow_through: how far past X_T' the capped step aims, m (module docstring).

    Returns:
        The steps and their intermediate quantities, each with leading axis N.
    """
    t_s = description.control_period
    rates = description.arm.joint_rate_limits
    theta = np.asarray(theta, dtype=float)
    x_e = forward_kinematics(theta)  # eq. 8
    predicted = np.asarray(target_position) + np.asarray(target_velocity) * t_s  # eq. 13
    offset = predicted - x_e
    distance = row_norms(offset)
    moving = np.isfinite(distance) & (distance != 0.0)  # else: no direction, no step
    n = np.zeros(offset.shape)
    u = np.zeros(offset.shape)
    lam_max = np.zeros(distance.shape)
    singular = np.zeros(distance.shape, dtype=bool)
    if moving.any():
        n[moving] = offset[moving] / distance[moving, None]  # eq. 14
        u[moving], singular[moving] = resolve_direction(
            theta[moving], n[moving], det_threshold, damping
        )  # eq. 16
        lam_max[moving] = lambda_max_of(u[moving], rates)  # eq. 18
    reach = np.where(moving, distance + follow_through, 0.0)
    speed = np.minimum(lam_max, reach / t_s) if cap else lam_max
    increment = speed[:, None] * u * t_s  # eq. 19
    return IncrementalStep(increment, n, u, lam_max, speed, singular)


class IncrementalIK(AnalyticController):
    """The paper's lambda_max controller (eqs. 13-19) as an
    [`capture_bench.agents.protocol.Agent`][capture_bench.agents.protocol.Agent].

    Args:
        description: the environment's public `TaskDescription` (the only thing it knows).
        cap: step cap on (default) or the paper's uncapped eqs. 13-19 (``cap=False``).
        det_threshold: |det J| (m^3) below which the DLS fallback replaces J^-1.
        damping: DLS damping mu, m.
        follow_through: how far past X_T' the capped step aims, m (module docstring; 0: it
            lands on X_T').
    """

    def __init__(
        self,
        description: TaskDescription,
        cap: bool = True,
        det_threshold: float = DET_THRESHOLD,
        damping: float = DAMPING,
        follow_through: float = 0.0,
    ) -> None:
        super().__init__(description)
        if not (math.isfinite(follow_through) and follow_through >= 0.0):
            raise ValueError(
                f"follow_through must be a finite length >= 0 m, got {follow_through!r}"
            )
        self.cap = cap
        self.follow_through = float(follow_through)
        self.det_threshold = det_threshold
        self.damping = damping
        #: the last call's eqs. 13-19, one row per observation (diagnostics)
        self.last_step: IncrementalStep | None = None

    def act_batch(self, observations: NDArray) -> NDArray[np.float32]:
        """Actions for N observations (eqs. 13-19), (N, 16) -> (N, 3), float32, in [-1, 1]."""
        obs = self.decode(observations)
        step = incremental_steps(
            obs.joint_angles,
            obs.target_position,
            obs.target_velocity,
            self.description,
            cap=self.cap,
            det_threshold=self.det_threshold,
            damping=self.damping,
            follow_through=self.follow_through,
        )
        self.last_step = step
        return safe_action(self.description.increment_to_action(step.increment))

    def reset(self) -> None:
        """Forget the last step's diagnostics."""
        super().reset()
        self.last_step = None
