"""The model of the paper's 12-state extended Kalman filter (section 2, eqs. 3-7).

State, in the camera frame, in the paper's order::

    X = (x, x_dot, y, y_dot, z, z_dot, theta_x, theta_x_dot, theta_y, theta_y_dot,
         theta_z, theta_z_dot)

where (x, y, z) is the origin of the target frame (the capture point), metres, and the Euler angles
give ``R_ct = Rz Ry Rx``, radians. Constant-velocity model per coordinate (eqs. 3-5) driven by
white acceleration noise ``omega`` with covariance ``Q = diag(sigma_a^2 x3, sigma_alpha^2 x3)``;
the process noise is ``B Q B^T``. Measurement (eq. 6): the image points of the four feature points
by eq. 2, flattened as (x_m1, z_m1, ..., x_m4, z_m4), with noise ``R = sigma_m^2 I_8``; ``H`` is
the analytic Jacobian (`capture_bench.sensing.photogrammetry.project_pose`).

The matrices here are the paper's, one step at a time, in its state order; the filter itself,
which runs them in the block order ``(q, q_dot)`` for many episodes at once, is
`capture_bench.sensing.estimator.TargetEstimator`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from capture_bench.sensing.photogrammetry import pose_projection

FloatArray = NDArray[np.float64]

POSE_INDEX = np.array([0, 2, 4, 6, 8, 10])  # (x, y, z, theta_x, theta_y, theta_z) in X
POSITION_VELOCITY_INDEX = np.array([0, 2, 4, 1, 3, 5])  # (x, y, z, x_dot, y_dot, z_dot) in X


_EYE12 = np.eye(12)
# Flat indices into a (12, 12) matrix: the t_s entries of A (eq. 4), and the 2 x 2 block
# (q q, q q_dot, q_dot q, q_dot q_dot) of each coordinate q in B Q B' (eq. 5).
_A_RATE_ENTRIES = POSE_INDEX * 12 + POSE_INDEX + 1
_BQB_ENTRIES = (POSE_INDEX * 13)[:, None] + np.array([0, 1, 12, 13])


def transition_matrices(dt: float) -> tuple[FloatArray, FloatArray]:
    """``A`` (12, 12) and ``B`` (12, 6) of eqs. 4-5 for a sampling interval ``dt`` (s)."""
    b = np.zeros((12, 6))
    b[POSE_INDEX, np.arange(6)] = 0.5 * dt * dt  # eq. 5: [t_s^2 / 2, t_s] blocks
    b[POSE_INDEX + 1, np.arange(6)] = dt
    return state_transition(dt), b


def state_transition(dt: float) -> FloatArray:
    """``A`` (12, 12) of eq. 4 for a sampling interval ``dt`` (s): [[1, t_s], [0, 1]] blocks."""
    a = _EYE12.copy()
    a.put(_A_RATE_ENTRIES, dt)
    return a


def process_noise(dt: float, variances: Sequence[float]) -> FloatArray:
    """``B Q B'`` (12, 12) of eq. 5 for a sampling interval ``dt`` (s) and ``Q = diag(variances)``
    (sigma_a^2 x3, sigma_alpha^2 x3; (m/s^2)^2 and (rad/s^2)^2).

    B has one non-zero per row (``t_s^2 / 2`` or ``t_s``), so every entry of the matrix product
    ``B @ Q @ B.T`` is one product ``(b_i q_j) b_l`` and the rest exact zeros: written out, the
    same floats, bit for bit (``tests/test_estimator.py``), without two matrix products.
    """
    half = 0.5 * dt * dt
    values: list[float] = []
    for q in variances:
        half_q, dt_q = half * q, dt * q  # (B Q)[i, j] = b_i q_j
        values += (half_q * half, half_q * dt, dt_q * half, dt_q * dt)
    out = np.zeros((12, 12))
    out.put(_BQB_ENTRIES, values)
    return out


#: The least pixel noise R assumes where the camera's noise is set, not measured: a noise-free
#: camera's filter stays well conditioned.
NOISE_FLOOR_PX = 0.25


def measurement_sigma(noise_px: float, pixel_pitch: float, noise_floor_px: float) -> float:
    """sigma_m of R = sigma_m^2 I (eq. 6), metres: ``max(noise_px, noise_floor_px)`` pixels."""
    return max(noise_px, noise_floor_px) * pixel_pitch


def wrap_angle(angle: FloatArray | float) -> FloatArray | float:
    """Euler angle(s) moved into [-pi, pi) by whole turns (h is 2 pi-periodic in them)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def default_initial_covariance() -> FloatArray:
    """Prior covariance (12, 12) around a photogrammetry pose, velocities unknown (zero mean).

    Standard deviations: position 0.05 m, angles 0.2 rad, linear velocity 0.5 m/s, angular
    velocity 1 rad/s.
    """
    sd = np.empty(12)
    sd[POSE_INDEX[:3]] = 0.05
    sd[POSE_INDEX[3:]] = 0.2
    sd[POSE_INDEX[:3] + 1] = 0.5
    sd[POSE_INDEX[3:] + 1] = 1.0
    return np.diag(sd**2)


def measurement(x: FloatArray, feature_points: FloatArray, focal_length: float) -> FloatArray:
    """h(X) of eq. 6 for a state X (12,): image points flattened (2N,), metres."""
    return pose_projection(np.asarray(x)[POSE_INDEX], feature_points, focal_length)[0]


def measurement_jacobian(
    x: FloatArray, feature_points: FloatArray, focal_length: float
) -> FloatArray:
    """H = dh/dX (2N, 12), analytic (the rate columns are zero)."""
    jac = pose_projection(np.asarray(x)[POSE_INDEX], feature_points, focal_length)[1]
    out = np.zeros((jac.shape[0], 12))
    out[:, POSE_INDEX] = jac
    return out
