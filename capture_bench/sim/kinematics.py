"""Kinematics of the 3-joint arm of Dong & Zhu (2016), Table 1.

Frames and conventions (see ``docs/architecture.md``):

* Global frame at the centre of joint 2, z up. The floor is at ``z = -L0``.
* Joint 1 rotates about global z; joints 2 and 3 are pitch joints.
* ``theta3 = 0`` means the forearm is *perpendicular* to the upper arm. This is the only reading of
  the paper's home pose ``(0, 90 deg, 0)`` that is not singular.

Forward kinematics (eq. 8)::

    r = l1 cos(theta2) + l2 sin(theta2 + theta3)
    x = r cos(theta1),  y = r sin(theta1)
    z = l1 sin(theta2) - l2 cos(theta2 + theta3)

All functions are pure and accept a single joint vector of shape (3,) or a batch of shape (N, 3).
Angles are radians, lengths metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

# Table 1 of the paper.
L0 = 0.1778  # base column, floor mount to joint 2 [m]; not part of the kinematics
L1 = 0.454025  # upper arm [m]
L2 = 0.4445  # forearm [m]
JOINT_RATE_LIMITS = np.array([10.304, 0.412, 0.412])  # theta_dot_max [rad/s]
HOME = np.array([0.0, np.pi / 2, 0.0])  # [rad]

# Joint position limits: ours (the paper only says it limits the workspace to avoid singularities).
# Inside this box r >= 0.073 m (away from the shoulder singularity r = 0) and |theta3| <= 70 deg
# (away from the elbow singularity theta3 = +-90 deg), so det J never vanishes; see tests.
JOINT_LOWER = np.radians([-170.0, 20.0, -70.0])
JOINT_UPPER = np.radians([170.0, 100.0, 60.0])

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ArmSpec:
    """The arm's published constants: what every agent may know.

    Attributes:
        link_lengths: (l0, l1, l2) in metres.
        joint_rate_limits: theta_dot_max per joint, rad/s, shape (3,).
        joint_lower: lower joint limits, rad, shape (3,).
        joint_upper: upper joint limits, rad, shape (3,).
        home: home joint angles, rad, shape (3,).
    """

    link_lengths: tuple[float, float, float] = (L0, L1, L2)
    joint_rate_limits: FloatArray = field(default_factory=lambda: JOINT_RATE_LIMITS.copy())
    joint_lower: FloatArray = field(default_factory=lambda: JOINT_LOWER.copy())
    joint_upper: FloatArray = field(default_factory=lambda: JOINT_UPPER.copy())
    home: FloatArray = field(default_factory=lambda: HOME.copy())


class ArmPose(NamedTuple):
    """M poses of the arm as eq. 8 and its Jacobian use them: the sines and cosines of
    theta_1, theta_2 and theta_2 + theta_3, r = L1 cos(theta_2) + L2 sin(theta_2 + theta_3) (the
    end effector's distance from the base axis) and X_E, (M,) each and (M, 3), evaluated once
    (`arm_pose`) for the position and the velocity of the same pose."""

    cos1: FloatArray
    sin1: FloatArray
    cos2: FloatArray
    sin2: FloatArray
    cos23: FloatArray
    sin23: FloatArray
    r: FloatArray
    x_e: FloatArray

    def take(self, index: slice | NDArray[np.intp]) -> ArmPose:
        """The poses ``index`` of these."""
        return ArmPose(*(value[index] for value in self))


def arm_pose(theta: ArrayLike) -> ArmPose:
    """`ArmPose` of joint angles ``theta``, rad, shape (3,) or (M, 3) (X_E: eq. 8)."""
    q = np.asarray(theta, dtype=float)
    angles = q.copy()  # theta_1, theta_2, theta_2 + theta_3: one sine and one cosine call
    angles[..., 2] += q[..., 1]
    cos, sin = np.cos(angles), np.sin(angles)
    cos1, cos2, cos23 = cos[..., 0], cos[..., 1], cos[..., 2]
    sin1, sin2, sin23 = sin[..., 0], sin[..., 1], sin[..., 2]
    r = L1 * cos2 + L2 * sin23
    out = np.empty(q.shape)
    out[..., 0] = r * cos1
    out[..., 1] = r * sin1
    out[..., 2] = L1 * sin2 - L2 * cos23
    return ArmPose(cos1, sin1, cos2, sin2, cos23, sin23, r, out)


def forward_kinematics(theta: ArrayLike) -> FloatArray:
    """End-effector position X_E = f(Theta) (eq. 8).

    Args:
        theta: joint angles, rad, shape (3,) or (N, 3).

    Returns:
        End-effector position in the global frame, metres, shape (3,) or (N, 3).
    """
    return arm_pose(theta).x_e


def elbow_position(theta: ArrayLike) -> FloatArray:
    """Position of joint 3 (the elbow) in the global frame, metres, shape (3,) or (N, 3)."""
    q = np.asarray(theta, dtype=float)
    t1, t2 = q[..., 0], q[..., 1]
    r = L1 * np.cos(t2)
    return np.stack([r * np.cos(t1), r * np.sin(t1), L1 * np.sin(t2)], axis=-1)


def jacobian(theta: ArrayLike) -> FloatArray:
    """Analytic Jacobian J = df/dTheta (eq. 9), metres per radian: shape (..., 3, 3) for joint
    angles of shape (..., 3), so (3, 3) for one joint vector (3,)."""
    q = np.asarray(theta, dtype=float)
    t1, t2, t3 = q[..., 0], q[..., 1], q[..., 2]
    c1, s1 = np.cos(t1), np.sin(t1)
    r = L1 * np.cos(t2) + L2 * np.sin(t2 + t3)
    dr2 = -L1 * np.sin(t2) + L2 * np.cos(t2 + t3)
    dr3 = L2 * np.cos(t2 + t3)
    dz2 = L1 * np.cos(t2) + L2 * np.sin(t2 + t3)
    dz3 = L2 * np.sin(t2 + t3)
    out = np.empty(q.shape[:-1] + (3, 3))  # filled entry by entry: no stacking of temporaries
    out[..., 0, 0] = -r * s1
    out[..., 0, 1] = dr2 * c1
    out[..., 0, 2] = dr3 * c1
    out[..., 1, 0] = r * c1
    out[..., 1, 1] = dr2 * s1
    out[..., 1, 2] = dr3 * s1
    out[..., 2, 0] = 0.0
    out[..., 2, 1] = dz2
    out[..., 2, 2] = dz3
    return out


def jacobian_determinant(theta: ArrayLike) -> FloatArray:
    """det J = l1 l2 r cos(theta3) (closed form), m^3; zero at r = 0 or theta3 = +-90 deg."""
    q = np.asarray(theta, dtype=float)
    t2, t3 = q[..., 1], q[..., 2]
    r = L1 * np.cos(t2) + L2 * np.sin(t2 + t3)
    return L1 * L2 * r * np.cos(t3)


def within_limits(
    theta: ArrayLike,
    lower: ArrayLike = JOINT_LOWER,
    upper: ArrayLike = JOINT_UPPER,
    tol: float = 1e-12,
) -> NDArray[np.bool_]:
    """Whether joint angles lie inside [lower, upper] (inclusive, with ``tol`` rad slack)."""
    q = np.asarray(theta, dtype=float)
    return np.all((q >= np.asarray(lower) - tol) & (q <= np.asarray(upper) + tol), axis=-1)


def inverse_kinematics(positions: ArrayLike) -> FloatArray:
    """Every closed-form solution of f(Theta) = X, for each point X.

    There are up to four: joint 1 facing the point (r > 0) or facing away (r < 0), each with two
    elbow solutions (equal where the point is on the edge of the reach, sin(theta3) = +-1).
    Angles are wrapped to [-pi, pi). No joint limits are applied; use `within_limits` to filter.

    Args:
        positions: points in the global frame, metres, shape (..., 3); one point (3,) is the
            case of no leading axes.

    Returns:
        Solutions, rad, shape (..., 4, 3), ordered (facing, elbow +), (facing, elbow -),
        (away, elbow +), (away, elbow -); rows of NaN where the point is out of reach.
    """
    positions = np.asarray(positions, dtype=float)
    p = positions.reshape(-1, 3)
    rho = np.hypot(p[:, 0], p[:, 1])
    base = np.arctan2(p[:, 1], p[:, 0])
    z = p[:, 2]
    out = np.full((p.shape[0], 4, 3), np.nan)
    # Planar 2-link problem. Expanding sin/cos(theta2 + theta3):
    #   r = (l1 + l2 s3) c2 + l2 c3 s2 = a c2 + b s2
    #   z = (l1 + l2 s3) s2 - l2 c3 c2 = a s2 - b c2
    # so r^2 + z^2 = a^2 + b^2 = l1^2 + l2^2 + 2 l1 l2 s3.
    s3 = (rho * rho + z * z - L1 * L1 - L2 * L2) / (2.0 * L1 * L2)
    ok = np.abs(s3) <= 1.0 + 1e-12
    s3 = np.clip(s3, -1.0, 1.0)
    c3_abs = np.sqrt(1.0 - s3 * s3)
    column = 0
    for sign_r, t1 in ((1.0, base), (-1.0, base + np.pi)):
        r = sign_r * rho
        for c3 in (c3_abs, -c3_abs):
            a, b = L1 + L2 * s3, L2 * c3
            t2 = np.arctan2(a * z + b * r, a * r - b * z)
            sol = np.stack([t1, t2, np.arctan2(s3, c3)], axis=-1)
            out[:, column] = np.where(ok[:, None], _wrap_array(sol), np.nan)
            column += 1
    return out.reshape(positions.shape[:-1] + (4, 3))


def reachable(
    positions: ArrayLike, lower: ArrayLike | None = None, upper: ArrayLike | None = None
) -> NDArray[np.bool_]:
    """Whether points (global, m, shape (..., 3)) have an IK solution inside the joint limits:
    (...,) bool.

    With the published limits (``lower``, ``upper`` None) only the solutions with joint 1 facing
    the point (r > 0) are tried, both elbows: inside those limits r > 0 always (see the module
    docstring). Other limits: every solution of `inverse_kinematics`.
    """
    p = np.asarray(positions, dtype=float)
    if lower is not None or upper is not None:
        lower = JOINT_LOWER if lower is None else lower
        upper = JOINT_UPPER if upper is None else upper
        return np.any(within_limits(inverse_kinematics(p), lower, upper), axis=-1)
    lo, hi = JOINT_LOWER, JOINT_UPPER
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    t1 = np.arctan2(y, x)
    r = np.hypot(x, y)
    s3 = (r * r + z * z - L1 * L1 - L2 * L2) / (2.0 * L1 * L2)
    inside = np.abs(s3) <= 1.0
    c3_abs = np.sqrt(np.where(inside, 1.0 - s3 * s3, 0.0))
    ok = np.zeros(p.shape[:-1], dtype=bool)
    for c3 in (c3_abs, -c3_abs):
        a, b = L1 + L2 * s3, L2 * c3
        t2 = np.arctan2(a * z + b * r, a * r - b * z)
        t3 = np.arctan2(s3, c3)
        ok |= (lo[1] <= t2) & (t2 <= hi[1]) & (lo[2] <= t3) & (t3 <= hi[2])
    return ok & inside & (lo[0] <= t1) & (t1 <= hi[0])


def _wrap_array(angles: FloatArray) -> FloatArray:
    """Wrap angles to [-pi, pi)."""
    return (angles + np.pi) % (2.0 * np.pi) - np.pi
