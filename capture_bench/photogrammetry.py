"""Photogrammetry: the target's pose from one image of its four feature points (paper section 2).

Unknowns: the pose ``(x_To, y_To, z_To, theta_x, theta_y, theta_z)`` of the target frame in the
camera frame, with ``R_ct = Rz(theta_z) @ Ry(theta_y) @ Rx(theta_x)``. Each feature point p_i
(target frame) lands at ``p_C = t + R_ct p_i`` (eq. 1) and is imaged by eq. 2, giving two equations
per point: eight equations, six unknowns, solved by damped Gauss-Newton (Levenberg-Marquardt) on an
analytic Jacobian. Without an initial guess the solver starts from the 24 rotations of the cube
group, solves the image equations for the translation exactly (they are linear in it once the
rotation is fixed), and keeps the lowest-residual converged solution.

The functions here are pure; :func:`pose_projection` is shared with the EKF (its measurement model
h and Jacobian H, eq. 6).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.rotations import euler_to_matrix, matrix_to_euler

FloatArray = NDArray[np.float64]


def rotation_and_derivatives(angles: FloatArray) -> FloatArray:
    """``R = Rz Ry Rx`` and its Euler-angle derivatives, packed for one matrix product.

    Args:
        angles: (theta_x, theta_y, theta_z), radians.

    Returns:
        ``M`` (3, 12) such that for target-frame points ``P`` (N, 3), ``P @ M[:, :3] = (R P^T)^T``
        and ``(P @ M[:, 3:]).reshape(N, 3, 3)[n, a, k] = (dR/dtheta_k @ p_n)[a]``.
    """
    ax, ay, az = float(angles[0]), float(angles[1]), float(angles[2])
    cx, sx, cy, sy = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay)
    cz, sz = math.cos(az), math.sin(az)
    r00, r01, r02 = cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx
    r10, r11, r12 = sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx
    r20, r21, r22 = -sy, cy * sx, cy * cx
    # dR/dtheta_y = Rz (dRy/dtheta_y) Rx, written out (y_ab = its entry a, b).
    y00, y01, y02 = -cz * sy, cz * cy * sx, cz * cy * cx
    y10, y11, y12 = -sz * sy, sz * cy * sx, sz * cy * cx
    y20, y21, y22 = -cy, -sy * sx, -sy * cx
    # dR/dtheta_x = R [e_x]x has columns (0, R e_z, -R e_y); dR/dtheta_z = [e_z]x R has rows
    # (-R row 1, R row 0, 0). Row b of M: R[:, b], then (dR_x, dR_y, dR_z)[a, b] for a = 0, 1, 2.
    return np.array(
        [
            [r00, r10, r20, 0.0, y00, -r10, 0.0, y10, r00, 0.0, y20, 0.0],
            [r01, r11, r21, r02, y01, -r11, r12, y11, r01, r22, y21, 0.0],
            [r02, r12, r22, -r01, y02, -r12, -r11, y12, r02, -r21, y22, 0.0],
        ]
    )


def pose_projection(
    pose: FloatArray, feature_points: FloatArray, focal_length: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Image of the feature points for a pose (eqs. 1-2) and its analytic Jacobian.

    Args:
        pose: (x_To, y_To, z_To, theta_x, theta_y, theta_z), camera frame, metres and radians.
        feature_points: feature points in the target frame, metres, shape (N, 3).
        focal_length: f, metres.

    Returns:
        ``h`` image points flattened as (x_m1, z_m1, x_m2, ...), metres, shape (2N,);
        ``J = dh / dpose``, shape (2N, 6); ``depth = y_C - f`` per point, metres, shape (N,).
    """
    f = focal_length
    n = feature_points.shape[0]
    pm = feature_points @ rotation_and_derivatives(pose[3:])
    p_c = pm[:, :3] + pose[:3]  # eq. 1: t + R_ct p_i
    d_rot = pm[:, 3:].reshape(n, 3, 3)  # d p_C / d theta, (N, 3, 3)
    depth = p_c[:, 1] - f
    inv = 1.0 / depth
    h = p_c[:, 0::2] * (-f * inv)[:, None]  # eq. 2, (N, 2) = [x_m, z_m]
    # d[x_m, z_m]/d p_C = [[-f, -x_m, 0], [0, -z_m, -f]] / (y_C - f), per point.
    w = np.zeros((n, 2, 3))
    w[:, 0, 0] = -f
    w[:, 1, 2] = -f
    w[:, :, 1] = -h
    w *= inv[:, None, None]
    jac = np.concatenate([w, w @ d_rot], axis=2).reshape(2 * n, 6)
    return h.reshape(2 * n), jac, depth


@dataclass
class PoseSolution:
    """Result of :func:`solve_pose`.

    Attributes:
        pose: (x_To, y_To, z_To, theta_x, theta_y, theta_z) of the target frame in the camera
            frame, metres and radians (theta_y in [-pi/2, pi/2]), shape (6,).
        converged: the iteration met its tolerance with every point in front of the lens.
        iterations: Gauss-Newton iterations of the returned solution.
        residual_rms: root-mean-square image residual over the 2N equations, metres.
    """

    pose: FloatArray
    converged: bool
    iterations: int
    residual_rms: float


def _cube_rotations() -> list[FloatArray]:
    """The 24 proper rotations that map the coordinate axes onto themselves, as Euler angles."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[range(3), perm] = signs
            if np.linalg.det(m) > 0:
                out.append(matrix_to_euler(m))
    return out


_CUBE_STARTS = _cube_rotations()


def translation_for_rotation(
    image_points: FloatArray, feature_points: FloatArray, rotation: FloatArray, focal_length: float
) -> FloatArray:
    """Least-squares translation for a fixed rotation; eqs. 1-2 are linear in it.

    ``u_i (t_y + q_yi - f) = -f (t_x + q_xi)`` and likewise for z, with ``q_i = R p_i``.

    Returns:
        (x_To, y_To, z_To), camera frame, metres, shape (3,).
    """
    f = focal_length
    q = feature_points @ rotation.T
    u, v = image_points[:, 0], image_points[:, 1]
    n = u.shape[0]
    a = np.zeros((2 * n, 3))
    a[0::2, 0] = f
    a[0::2, 1] = u
    a[1::2, 2] = f
    a[1::2, 1] = v
    b = np.empty(2 * n)
    b[0::2] = -u * (q[:, 1] - f) - f * q[:, 0]
    b[1::2] = -v * (q[:, 1] - f) - f * q[:, 2]
    return np.linalg.lstsq(a, b, rcond=None)[0]


def _refine(
    z: FloatArray,
    feature_points: FloatArray,
    focal_length: float,
    pose0: FloatArray,
    max_iterations: int,
    tol: float,
) -> PoseSolution:
    """Levenberg-Marquardt from ``pose0`` on the 2N image equations."""
    pose = np.array(pose0, dtype=float)
    h, jac, depth = pose_projection(pose, feature_points, focal_length)
    if np.any(depth <= 0):
        return PoseSolution(pose, False, 0, float("inf"))
    r = h - z
    cost = float(r @ r)
    damping = 1e-6
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007 - the count is reported
        jtj = jac.T @ jac
        grad = jac.T @ r
        step = None
        while damping < 1e12:
            a = jtj + damping * np.diag(np.diag(jtj) + 1e-12)
            try:
                step = -np.linalg.solve(a, grad)
            except np.linalg.LinAlgError:
                damping *= 10.0
                continue
            trial = pose + step
            h_t, jac_t, depth_t = pose_projection(trial, feature_points, focal_length)
            r_t = h_t - z
            cost_t = float(r_t @ r_t)
            if np.all(depth_t > 0) and cost_t <= cost:
                pose, h, jac, r, cost = trial, h_t, jac_t, r_t, cost_t
                damping = max(damping * 0.1, 1e-9)
                break
            damping *= 10.0
        else:
            # No step decreases the cost: we sit at a (local) minimum to machine precision.
            converged = True
            break
        if step is not None and np.max(np.abs(step)) <= tol * (1.0 + np.max(np.abs(pose))):
            converged = True
            break
    rms = float(np.sqrt(cost / z.shape[0]))
    return PoseSolution(pose, converged and np.isfinite(rms), it, rms)


def _rank(sol: PoseSolution) -> tuple[bool, float]:
    """Order of preference among starts: converged first, then the smaller residual."""
    return sol.converged, -sol.residual_rms


def _canonical(pose: FloatArray) -> FloatArray:
    """Same pose with the Euler angles in the canonical range of ``matrix_to_euler``."""
    out = pose.copy()
    out[3:] = matrix_to_euler(euler_to_matrix(pose[3:]))
    return out


def solve_pose(
    image_points: ArrayLike,
    feature_points: ArrayLike,
    focal_length: float,
    initial_guess: ArrayLike | None = None,
    max_iterations: int = 50,
    tol: float = 1e-10,
) -> PoseSolution:
    """Pose of the target in the camera frame from one image (eqs. 1-2, iterative least squares).

    Args:
        image_points: measured ``[x_m, z_m]`` of the feature points, metres, shape (N, 2), N >= 3.
        feature_points: the same points in the target frame, metres, shape (N, 3).
        focal_length: f, metres.
        initial_guess: pose (6,) to start from (warm start). If that start does not converge the
            solver falls back to the multi-start below. None: start from each of the 24 cube
            rotations with its exact least-squares translation and keep the converged solution
            of least residual.
        max_iterations: Gauss-Newton iterations per start.
        tol: convergence when the largest step component <= tol * (1 + max |pose|).

    Returns:
        The :class:`PoseSolution` (the best start, converged or not).
    """
    z = np.asarray(image_points, dtype=float).reshape(-1)
    pts = np.asarray(feature_points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or z.shape[0] != 2 * pts.shape[0]:
        raise ValueError(
            f"need image_points (N, 2) and feature_points (N, 3); got {z.shape[0]} image values "
            f"for feature points of shape {pts.shape}"
        )
    if initial_guess is not None:
        sol = _refine(z, pts, focal_length, np.asarray(initial_guess, float), max_iterations, tol)
        if sol.converged:
            sol.pose = _canonical(sol.pose)
            return sol
    best: PoseSolution | None = None
    uv = z.reshape(-1, 2)
    for angles in _CUBE_STARTS:
        rot = euler_to_matrix(angles)
        t = translation_for_rotation(uv, pts, rot, focal_length)
        sol = _refine(z, pts, focal_length, np.concatenate([t, angles]), max_iterations, tol)
        if best is None or _rank(sol) > _rank(best):
            best = sol
    assert best is not None
    best.pose = _canonical(best.pose)
    return best
