"""The target's pose from three feature points (P3P): its candidates and how to tell them apart.

Photogrammetry (`capture_bench.sensing.photogrammetry.solve_poses`) solves the eight image
equations of four points. Three points give six equations for the six unknowns, which fix the
pose up to at most four solutions (the paper, section 2: three points suffice in theory).
`three_point_poses` finds them with OpenCV's closed-form P3P; `candidate_residuals` scores each
candidate against another frame's points, and `pick_candidate` keeps the one candidate that
frame leaves consistent, if there is exactly one. `consensus_candidate` is the prior's way out
when no frame has told them apart: candidates that all lie within a given spread of one of them
(the filter's prior standard deviations) are one estimate as far as the filter is concerned.

The camera of eq. 2 and OpenCV's pinhole: the camera frame's origin is the centre of the image
plane, its y-axis points toward the scene and the lens sits at ``y = f``; eq. 2 is
``x_m = -f x_C / (y_C - f)``, ``z_m = -f z_C / (y_C - f)`` (metres on the image plane). OpenCV's
camera frame has its origin at the lens and its Z axis along the optical axis. With

    ``p_cv = M (p_C - (0, f, 0))``, ``M = [[-1, 0, 0], [0, 0, 1], [0, 1, 0]]`` (a proper rotation),

``X_cv / Z_cv = x_m / f`` and ``Y_cv / Z_cv = -z_m / f``: OpenCV's normalised image point of
``(x_m / f, -z_m / f)`` with the identity camera matrix is eq. 2. An OpenCV pose
``p_cv = R_cv p + t_cv`` of a target-frame point p is the pose of eq. 1 with
``R_ct = M' R_cv`` and ``t = M' t_cv + (0, f, 0)``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.photogrammetry import (
    levenberg_marquardt,
    project_poses,
    projection_table,
)
from capture_bench.sim.rotations import euler_to_matrix, matrix_to_euler

FloatArray = NDArray[np.float64]

# Camera frame (less the lens offset) -> OpenCV camera frame, a proper rotation (det +1).
CAMERA_TO_OPENCV = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
MAX_CANDIDATES = 4  # P3P has at most four solutions
P3P_METHOD = cv2.SOLVEPNP_AP3P  # Ke and Roumeliotis' algebraic P3P
REFINE_ITERATIONS = 50
REFINE_TOL = 1e-10


def _checked_three(image_points: ArrayLike, feature_points: ArrayLike) -> tuple[FloatArray, ...]:
    """image points (3, 2) and feature points (3, 3) as finite float arrays."""
    uv = np.asarray(image_points, dtype=float)
    pts = np.asarray(feature_points, dtype=float)
    if uv.shape != (3, 2) or pts.shape != (3, 3):
        raise ValueError(
            f"need image_points (3, 2) and feature_points (3, 3); got {uv.shape} and {pts.shape}"
        )
    if not (np.isfinite(uv).all() and np.isfinite(pts).all()):
        raise ValueError("image_points and feature_points must be finite")
    return uv, pts


def three_point_poses(
    image_points: ArrayLike, feature_points: ArrayLike, focal_length: float
) -> FloatArray:
    """The poses that image three feature points where they were seen (P3P, eqs. 1-2).

    Args:
        image_points: measured ``[x_m, z_m]`` of the three points, metres, shape (3, 2).
        feature_points: the same points in the target frame, metres, shape (3, 3).
        focal_length: f, metres.

    Returns:
        (K, 6) poses ``(x_To, y_To, z_To, theta_x, theta_y, theta_z)`` of the target frame in the
        camera frame (metres, radians, the angles of ``matrix_to_euler``), K <= 4: the P3P
        solutions with all three points beyond the lens, in OpenCV's order. (0, 6) when there is
        none (degenerate points or image).
    """
    uv, pts = _checked_three(image_points, feature_points)
    f = float(focal_length)
    normalised = np.stack([uv[:, 0] / f, -uv[:, 1] / f], axis=1)
    count, rvecs, tvecs = cv2.solveP3P(pts, normalised, np.eye(3), None, flags=P3P_METHOD)
    poses = []
    for rvec, tvec in zip(rvecs[:count], tvecs[:count], strict=True):
        r_cv = cv2.Rodrigues(np.asarray(rvec, dtype=float))[0]
        r_ct = CAMERA_TO_OPENCV.T @ r_cv
        t = CAMERA_TO_OPENCV.T @ np.asarray(tvec, dtype=float).reshape(3) + (0.0, f, 0.0)
        depth = (pts @ r_ct.T + t)[:, 1] - f  # y_C - f of each point
        if np.isfinite(t).all() and (depth > 0.0).all():
            poses.append(np.concatenate([t, matrix_to_euler(r_ct)]))
    return np.array(poses, dtype=float).reshape(-1, 6)


def candidate_residuals(
    candidates: ArrayLike, image_points: ArrayLike, feature_points: ArrayLike, focal_length: float
) -> FloatArray:
    """Image residual RMS of each candidate pose against one frame's seen points (eqs. 1-2).

    Args:
        candidates: (K, 6) poses, camera frame, metres and radians.
        image_points: ``[x_m, z_m]`` of every feature point, metres, (N, 2); NaN for a point not
            seen (at least one must be).
        feature_points: the target-frame points, metres, (N, 3).
        focal_length: f, metres.

    Returns:
        (K,) RMS over the seen points' coordinates, metres; inf for a candidate that puts a seen
        point at or behind the lens.
    """
    uv = np.asarray(image_points, dtype=float)
    seen = np.isfinite(uv).all(axis=1)
    if not seen.any():
        raise ValueError("candidate_residuals needs at least one seen point")
    poses = np.asarray(candidates, dtype=float).reshape(-1, 6)
    table = projection_table(np.asarray(feature_points, dtype=float)[seen], focal_length)
    rj, depth = project_poses(poses, table, uv[seen].T)
    rms = np.sqrt(np.mean(rj[:, 0] ** 2, axis=(1, 2)))
    return np.where((depth > 0.0).all(axis=1), rms, np.inf)


def pick_candidate(residuals: ArrayLike, max_residual: float) -> int | None:
    """The index of the one candidate whose residual is at most ``max_residual``; None when no
    candidate or more than one is (the frame does not tell them apart)."""
    consistent = np.flatnonzero(np.asarray(residuals, dtype=float) <= max_residual)
    return int(consistent[0]) if consistent.size == 1 else None


def consensus_candidate(candidates: ArrayLike, spread: ArrayLike) -> int | None:
    """The candidate that every candidate lies within ``spread`` of, component by component;
    None when there is none.

    Args:
        candidates: (K, 6) poses, camera frame, metres and radians, K >= 1.
        spread: (6,) largest difference allowed per coordinate, metres and radians (angle
            differences wrapped to [-pi, pi)).

    Returns:
        Among the candidates within ``spread`` of all the others, the one of least total
        normalised distance to them (the first on a tie); None when none is.
    """
    c = np.asarray(candidates, dtype=float).reshape(-1, 6)
    d = c[:, None, :] - c[None, :, :]  # (K, K, 6)
    d[:, :, 3:] = (d[:, :, 3:] + math.pi) % (2.0 * math.pi) - math.pi
    scaled = np.abs(d) / np.asarray(spread, dtype=float)
    within = (scaled <= 1.0).all(axis=(1, 2))
    if not within.any():
        return None
    total = np.where(within, scaled.sum(axis=(1, 2)), np.inf)
    return int(np.argmin(total))


def refine_pose(
    pose: ArrayLike, image_points: ArrayLike, feature_points: ArrayLike, focal_length: float
) -> tuple[FloatArray, bool, float]:
    """Levenberg-Marquardt on one frame's seen points (at least three) from ``pose``: the
    solution nearest it (`photogrammetry.levenberg_marquardt`, one start).

    Args:
        pose: (6,) starting pose, camera frame, metres and radians.
        image_points: ``[x_m, z_m]`` of every feature point, metres, (N, 2); NaN where not seen.
        feature_points: the target-frame points, metres, (N, 3).
        focal_length: f, metres.

    Returns:
        The pose (6,) (angles of ``matrix_to_euler``), whether it converged, and its residual RMS
        over the seen points' coordinates, metres.
    """
    uv = np.asarray(image_points, dtype=float)
    seen = np.isfinite(uv).all(axis=1)
    if np.count_nonzero(seen) < 3:
        raise ValueError("refine_pose needs at least three seen points")
    table = projection_table(np.asarray(feature_points, dtype=float)[seen], focal_length)
    start = np.asarray(pose, dtype=float).reshape(1, 6)
    out, conv, _, cost = levenberg_marquardt(
        uv[seen].T, table, start, REFINE_ITERATIONS, REFINE_TOL
    )
    refined = out[0].copy()
    refined[3:] = matrix_to_euler(euler_to_matrix(refined[3:]))
    rms = math.sqrt(float(cost[0]) / (2 * np.count_nonzero(seen)))
    return refined, bool(conv[0]) and math.isfinite(rms), rms
