"""Photogrammetry: the target's pose from one image of its four feature points (paper section 2).

Unknowns: the pose ``(x_To, y_To, z_To, theta_x, theta_y, theta_z)`` of the target frame in the
camera frame, with ``R_ct = Rz(theta_z) @ Ry(theta_y) @ Rx(theta_x)``. Each feature point p_i
(target frame) lands at ``p_C = t + R_ct p_i`` (eq. 1) and is imaged by eq. 2, giving two equations
per point: eight equations, six unknowns, solved by damped Gauss-Newton (Levenberg-Marquardt) on an
analytic Jacobian. Without an initial guess the solver starts from the 24 rotations of the cube
group, solves the image equations for the translation exactly (they are linear in it once the
rotation is fixed), runs all 24 starts together as one vectorised Levenberg-Marquardt (each start
follows its own damping schedule, as if run alone up to rounding) and keeps the lowest-residual
converged solution.

Evaluation: every entry of ``R_ct`` and of its three Euler-angle derivatives is a sum of products
``a_x a_y a_z`` with ``a_k`` one of ``(cos theta_k, sin theta_k, 1)``: 27 products. Eqs. 1-2's
numerators, denominators and their derivatives are therefore one constant matrix (the *projection
table*, fixed by the feature points and f) times the 31-vector ``(27 products, t, 1)``; the image
points and the Jacobian follow by the quotient rule. One matrix product serves any number of poses.

The functions here are pure; the projection table is shared with the EKF (its measurement model
h and Jacobian H, eq. 6).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.rotations import matrix_to_euler

FloatArray = NDArray[np.float64]

# Quantities per coordinate in a projection table: the value, then d/d(x_To, y_To, z_To), then
# d/d(theta_x, theta_y, theta_z).
N_QUANTITIES = 7
# Coordinates per point, in table order: the two numerators of eq. 2, then the denominator.
COORDINATE_AXES = (0, 2, 1)  # -f x_C, -f z_C, y_C - f
POSE_FEATURES = 31  # 27 angle products, the translation (3) and a constant 1


def _rotation_coefficients() -> FloatArray:
    """Coefficients of ``R = Rz Ry Rx`` and ``dR/dtheta_k`` over the 27 angle products.

    Returns:
        (4, 3, 3, 27): ``[0]`` is R, ``[1 + k]`` is dR/dtheta_k; entry ``[., a, b, 9 i + 3 j + l]``
        multiplies ``a_x[i] a_y[j] a_z[l]`` with ``a_k = (cos theta_k, sin theta_k, 1)``.
    """
    c, s, one = np.eye(3)  # cos, sin and 1 as coefficient vectors over (cos, sin, 1)
    z = np.zeros(3)
    rx = np.array([[one, z, z], [z, c, -s], [z, s, c]])
    ry = np.array([[c, z, s], [z, one, z], [-s, z, c]])
    rz = np.array([[c, -s, z], [s, c, z], [z, z, one]])
    # d/dtheta (alpha cos + beta sin + gamma) = beta cos - alpha sin.
    deriv = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])

    def product(mx: FloatArray, my: FloatArray, mz: FloatArray) -> FloatArray:
        return np.einsum("lja,klb,ikc->ijabc", mx, my, mz).reshape(3, 3, 27)

    dx, dy, dz = rx @ deriv.T, ry @ deriv.T, rz @ deriv.T
    return np.stack(
        [product(rx, ry, rz), product(dx, ry, rz), product(rx, dy, rz), product(rx, ry, dz)]
    )


_ROTATION_COEFFICIENTS = _rotation_coefficients()


@functools.lru_cache(maxsize=32)
def _cached_table(points: bytes, n: int, focal_length: float) -> FloatArray:
    p = np.frombuffer(points, dtype=float).reshape(n, 3)
    f = focal_length
    rot = np.einsum("qabm,nb->mqan", _ROTATION_COEFFICIENTS, p)  # (27, 4, 3, N): R p and dR p
    table = np.zeros((POSE_FEATURES, N_QUANTITIES, 3, n))
    for c, axis in enumerate(COORDINATE_AXES):
        table[:27, 0, c] = rot[:, 0, axis]  # eq. 1: (R p_i)[axis] ...
        table[:27, 4:, c] = rot[:, 1:, axis]
        table[27 + axis, 0, c] = 1.0  # ... + t[axis]
        table[30, 1 + axis, c] = 1.0  # d p_C[axis] / d t[axis]
    table[30, 0, 2] = -f  # denominator y_C - f
    table[:, :, :2] *= -f  # numerators -f x_C, -f z_C
    out = np.ascontiguousarray(table.reshape(POSE_FEATURES, -1).T)
    out.flags.writeable = False
    return out


def projection_table(feature_points: ArrayLike, focal_length: float) -> FloatArray:
    """The constant matrix of eqs. 1-2 for these feature points and focal length (cached).

    Args:
        feature_points: feature points in the target frame, metres, shape (N, 3).
        focal_length: f, metres.

    Returns:
        Read-only ``T`` (7 * 3 * N, 31) such that ``(T @ pose_features(pose)).reshape(7, 3, N)``
        holds, for quantity q (value, d/dt x3, d/dtheta x3), coordinate c (``-f x_C``, ``-f z_C``,
        ``y_C - f``) and point n, the derivative of that coordinate of point n.
    """
    p = np.ascontiguousarray(feature_points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"feature_points must have shape (N, 3), got {p.shape}")
    return _cached_table(p.tobytes(), p.shape[0], float(focal_length))


# Pose features as products of three entries of (cos x, sin x, cos y, sin y, cos z, sin z, t, 1):
# (a_x[i] a_y[j] a_z[l]) for a_k = (cos, sin, 1) of theta_k, then (t_x, t_y, t_z, 1) times 1 * 1.
_FEATURE_FACTORS = np.array(
    [(i, j, k) for i in (0, 1, 9) for j in (2, 3, 9) for k in (4, 5, 9)]
    + [(6, 9, 9), (7, 9, 9), (8, 9, 9), (9, 9, 9)]
)


def pose_features(poses: FloatArray) -> FloatArray:
    """The 31 pose features ``(27 angle products, t, 1)`` of poses (K, 6) -> (K, 31)."""
    cos_sin = np.exp(1j * poses[:, 3:]).view(float)  # (cos, sin) of each angle, (K, 6)
    src = np.concatenate((cos_sin, poses[:, :3], np.ones((poses.shape[0], 1))), axis=1)
    factors = src[:, _FEATURE_FACTORS]  # (K, 31, 3)
    return factors[:, :, 0] * factors[:, :, 1] * factors[:, :, 2]


def project_poses(
    poses: FloatArray, table: FloatArray, image: FloatArray | float = 0.0
) -> tuple[FloatArray, FloatArray]:
    """Eqs. 1-2, the residual against an image and the analytic Jacobian, for K poses at once.

    Args:
        poses: (K, 6) poses (x_To, y_To, z_To, theta_x, theta_y, theta_z), metres and radians.
        table: :func:`projection_table` of the feature points.
        image: measured image points, ``[0]`` the x_m and ``[1]`` the z_m of each point, metres,
            (2, N); 0 gives the image points themselves.

    Returns:
        ``rj`` (K, 7, 2, N): ``rj[k, 0, c, n] = h[k, c, n] - image[c, n]`` with h the image
        points (c = 0: x_m, c = 1: z_m) and ``rj[k, 1 + j] = dh[k] / dpose_j``;
        ``depth`` (K, N): ``y_C - f`` per point, metres.
    """
    k = poses.shape[0]
    g = (pose_features(poses) @ table.T).reshape(k, N_QUANTITIES, 3, -1)
    depth = g[:, 0, 2]
    g = g * (1.0 / depth)[:, None, None, :]  # eq. 2 and its quotient rule share 1 / (y_C - f)
    h = g[:, 0, :2]
    rj = g[:, :, :2] - h[:, None] * g[:, :, 2:]  # quotient rule; row 0 comes out as 0
    rj[:, 0] = h - image
    return rj, depth


def project_pose(
    pose: Sequence[float], table: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Eqs. 1-2 and their analytic Jacobian for one pose, with scalar trigonometry.

    The single-pose twin of :func:`project_poses` (same table, same products), for the EKF's
    per-step h and H where numpy's per-call cost dominates.

    Args:
        pose: (x_To, y_To, z_To, theta_x, theta_y, theta_z), metres and radians, 6 Python floats
            (``array.tolist()``: scalar arithmetic on numpy scalars is slower).
        table: :func:`projection_table` of the feature points.

    Returns:
        ``h`` (2, N): ``[0]`` the x_m and ``[1]`` the z_m of each point, metres;
        ``jt`` (6, 2, N): ``jt[j, c, n] = d h[c, n] / d pose_j``;
        ``depth`` (N,): ``y_C - f`` per point, metres.
    """
    tx, ty, tz, ax, ay, az = pose
    a_x = (math.cos(ax), math.sin(ax), 1.0)
    a_y = (math.cos(ay), math.sin(ay), 1.0)
    a_z = (math.cos(az), math.sin(az), 1.0)
    xy = [p * q for p in a_x for q in a_y]
    features = [p * q for p in xy for q in a_z]  # the order of _FEATURE_FACTORS
    features += (tx, ty, tz, 1.0)
    g = (table @ features).reshape(N_QUANTITIES, 3, -1)
    depth = g[0, 2]
    g = g * (1.0 / depth)  # eq. 2 and its quotient rule share 1 / (y_C - f); depth stays a view
    h = g[0, :2]
    return h, g[1:, :2] - h * g[1:, 2:], depth


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
    table = projection_table(feature_points, focal_length)
    h, jt, depth = project_pose(np.asarray(pose, dtype=float).reshape(6).tolist(), table)
    n = depth.shape[0]
    return h.T.reshape(2 * n), jt.transpose(2, 1, 0).reshape(2 * n, 6), depth


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


def _cube_rotations() -> tuple[FloatArray, FloatArray]:
    """The 24 proper rotations that map the coordinate axes onto themselves.

    Returns:
        (24, 3, 3) matrices and (24, 3) their Euler angles (``matrix_to_euler``).
    """
    mats, angles = [], []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[range(3), perm] = signs
            if np.linalg.det(m) > 0:
                mats.append(m)
                angles.append(matrix_to_euler(m))
    return np.array(mats), np.array(angles)


_CUBE_MATRICES, _CUBE_ANGLES = _cube_rotations()


def translations_for_rotations(
    image_points: FloatArray, rotated_points: FloatArray, focal_length: float
) -> FloatArray:
    """Least-squares translations for fixed rotations; eqs. 1-2 are linear in the translation.

    ``u_i (t_y + q_yi - f) = -f (t_x + q_xi)`` and likewise for z, with ``q_i = R p_i``. The
    matrix of the system depends on the image only, so one least-squares call serves every R.

    Args:
        image_points: measured ``[x_m, z_m]``, metres, shape (N, 2).
        rotated_points: ``q_i = R_k p_i`` for K rotations, metres, shape (K, N, 3).
        focal_length: f, metres.

    Returns:
        (K, 3) translations (x_To, y_To, z_To), camera frame, metres.
    """
    f = focal_length
    u, v = image_points[:, 0], image_points[:, 1]
    n = u.shape[0]
    a = np.zeros((2 * n, 3))
    a[0::2, 0] = f
    a[0::2, 1] = u
    a[1::2, 2] = f
    a[1::2, 1] = v
    q = rotated_points
    b = np.empty((2 * n, q.shape[0]))
    b[0::2] = (-u * (q[:, :, 1] - f) - f * q[:, :, 0]).T
    b[1::2] = (-v * (q[:, :, 1] - f) - f * q[:, :, 2]).T
    return np.linalg.lstsq(a, b, rcond=None)[0].T


def _solve_damped(
    a: FloatArray, grad: FloatArray
) -> tuple[NDArray[np.floating], NDArray[np.bool_] | None]:
    """Steps ``-a^-1 grad`` for (R, 6, 6) and (R, 6, 1); also which systems were solvable.

    The second result is None when all were (the common case).
    """
    try:
        return -np.linalg.solve(a, grad)[:, :, 0], None
    except np.linalg.LinAlgError:  # rare: solve one by one and report the singular ones
        step = np.zeros(grad.shape[:2])
        ok = np.ones(a.shape[0], dtype=bool)
        for i in range(a.shape[0]):
            try:
                step[i] = -np.linalg.solve(a[i], grad[i, :, 0])
            except np.linalg.LinAlgError:
                ok[i] = False
        return step, ok


MAX_DAMPING = 1e12  # no step at this damping or above is tried: the start sits at a minimum
MAX_SPECULATIVE_LEVELS = 24
_POWERS_OF_TEN = 10.0 ** np.arange(MAX_SPECULATIVE_LEVELS)


def _levenberg_marquardt(
    z: FloatArray, table: FloatArray, poses0: FloatArray, max_iterations: int, tol: float
) -> tuple[FloatArray, NDArray[np.bool_], NDArray[np.int_], FloatArray]:
    """Levenberg-Marquardt on the 2N image equations from K starts, all iterating together.

    Each start follows the schedule it would follow alone: it tries a step damped by
    ``lambda (diag(J^T J) + 1e-12)``; an accepted step (every point beyond the lens, cost not
    increased) divides lambda by 10 (not below 1e-9) and ends the iteration, a rejected one
    multiplies it by 10 and tries again. A start stops when an accepted step is within
    ``tol * (1 + max |pose|)`` (converged), when no lambda below ``MAX_DAMPING`` is accepted (a
    minimum to machine precision: converged), or after ``max_iterations`` iterations (not
    converged). A start with a point at or behind the lens is dropped at once (not converged).

    Rejections come in runs (near a minimum, up to ~20 in a row while lambda climbs), and J and
    the residual do not change within a run. So after a rejection a start tries all the next
    lambdas at once (up to ``MAX_SPECULATIVE_LEVELS``) and keeps the first accepted one: the
    outcome of trying them one by one, in one round instead of many.

    Args:
        z: measured image points, ``[0]`` the x_m and ``[1]`` the z_m of each point, (2, N).
        table: :func:`projection_table` of the feature points.
        poses0: (K, 6) starting poses.

    Returns:
        Final poses (K, 6), converged (K,), iterations (K,), cost = sum of squared residuals (K,).
    """
    k = poses0.shape[0]
    poses = np.array(poses0, dtype=float)
    converged = np.zeros(k, dtype=bool)
    iterations = np.zeros(k, dtype=int)
    costs = np.full(k, np.inf)
    rj, depth = project_poses(poses, table, z)
    live = np.flatnonzero((depth > 0).all(axis=1))
    if live.size == 0:
        return poses, converged, iterations, costs
    n_eq = z.size
    pose = poses[live]
    rj = rj[live].reshape(-1, 7, n_eq)  # rows: the residual (2N), then J^T (6, 2N)
    cost = np.einsum("ij,ij->i", rj[:, 0], rj[:, 0])
    damping = np.full(live.size, 1e-6)
    it = np.ones(live.size, dtype=int)
    levels = None  # lambdas per start this round when some start is in a run of rejections
    while True:
        gram = rj @ rj.transpose(0, 2, 1)  # [[r.r, (J^T r)^T], [J^T r, J^T J]], (M, 7, 7)
        lam, base, base_cost = damping, pose, cost
        if levels is not None:  # one row per lambda tried: start i owns rows [first[i], ...)
            owner = np.repeat(np.arange(levels.size), levels)
            first = np.cumsum(levels) - levels
            lam = damping[owner] * _POWERS_OF_TEN[np.arange(owner.size) - first[owner]]
            gram, base, base_cost = gram[owner], pose[owner], cost[owner]
        diag = gram.reshape(-1, 49)[:, 8::8]  # the diagonal of J^T J
        diag += lam[:, None] * (diag + 1e-12)  # J^T J + lambda (diag(J^T J) + 1e-12)
        step, solvable = _solve_damped(gram[:, 1:, 1:], gram[:, 1:, :1])
        trial = base + step
        rj_t, depth_t = project_poses(trial, table, z)
        rj_t = rj_t.reshape(-1, 7, n_eq)
        cost_t = np.einsum("ij,ij->i", rj_t[:, 0], rj_t[:, 0])
        accept = (depth_t > 0).all(axis=1) & (cost_t <= base_cost)
        if solvable is not None:
            accept &= solvable
        if levels is not None:  # keep each start's first accepted lambda, else its last one
            rows = np.where(accept, np.arange(accept.size), accept.size)
            first_ok = np.minimum.reduceat(rows, first)
            last = first + levels - 1
            accept = first_ok <= last
            row = np.where(accept, first_ok, last)
            trial, step, rj_t, cost_t, lam = trial[row], step[row], rj_t[row], cost_t[row], lam[row]
        reject = ~accept
        if levels is None and not reject.any():  # the common round: every start moves
            pose, rj, cost = trial, rj_t, cost_t
        else:
            pose = np.where(accept[:, None], trial, pose)
            rj = np.where(accept[:, None, None], rj_t, rj)
            cost = np.where(accept, cost_t, cost)
        damping = lam * np.where(accept, 0.1, 10.0)
        np.maximum(damping, 1e-9, out=damping, where=accept)
        small = np.abs(step).max(axis=1) <= tol * (1.0 + np.abs(pose).max(axis=1))
        stalled = reject & (damping >= MAX_DAMPING)  # no step decreases the cost: a minimum
        done_ok = (accept & small) | stalled
        done = done_ok | (accept & (it >= max_iterations))
        it += accept & ~done
        levels = None
        if reject.any():
            levels = np.where(reject, (damping[:, None] * _POWERS_OF_TEN < MAX_DAMPING).sum(1), 1)
        if done.any():
            idx = live[done]
            poses[idx] = pose[done]
            converged[idx] = done_ok[done]
            iterations[idx] = it[done]
            costs[idx] = cost[done]
            keep = ~done
            if not keep.any():
                break
            live, pose, rj, cost = live[keep], pose[keep], rj[keep], cost[keep]
            damping, it = damping[keep], it[keep]
            if levels is not None:
                levels = levels[keep]
    return poses, converged, iterations, costs


def _canonical(pose: FloatArray) -> FloatArray:
    """Same pose with the Euler angles in the canonical range of ``matrix_to_euler``.

    The round trip ``matrix_to_euler(euler_to_matrix(angles))``, using only the five entries of
    R that ``matrix_to_euler`` reads.
    """
    ax, ay, az = float(pose[3]), float(pose[4]), float(pose[5])
    cx, sx, cy, sy = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay)
    cz, sz = math.cos(az), math.sin(az)
    out = pose.copy()
    out[3] = math.atan2(cy * sx, cy * cx)
    out[4] = math.asin(min(max(sy, -1.0), 1.0))
    out[5] = math.atan2(sz * cy, cz * cy)
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
    uv = np.asarray(image_points, dtype=float)
    pts = np.asarray(feature_points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or uv.size != 2 * pts.shape[0]:
        raise ValueError(
            f"need image_points (N, 2) and feature_points (N, 3); got {uv.size} image values "
            f"for feature points of shape {pts.shape}"
        )
    uv = uv.reshape(-1, 2)
    z = uv.T  # (2, N): the x_m row, then the z_m row
    table = projection_table(pts, focal_length)
    n_eq = uv.size
    if initial_guess is not None:
        start = np.asarray(initial_guess, dtype=float).reshape(1, 6)
        pose, conv, its, cost = _levenberg_marquardt(z, table, start, max_iterations, tol)
        rms = math.sqrt(cost[0] / n_eq)
        if conv[0] and math.isfinite(rms):
            return PoseSolution(_canonical(pose[0]), True, int(its[0]), rms)
    cold = _solve_cold(
        uv.tobytes(), pts.tobytes(), pts.shape[0], float(focal_length), max_iterations, tol
    )
    return dataclasses.replace(cold, pose=cold.pose.copy())  # the cached one stays untouched


# The multi-start costs ~5 ms and is a pure function of the image: an evaluation that runs several
# agents on one seed images the same first frame each time (reset draws it before any agent
# acts), so it is solved once per process. Keyed by the exact bytes, like the projection table.
@functools.lru_cache(maxsize=4096)
def _solve_cold(
    image: bytes, points: bytes, n: int, focal_length: float, max_iterations: int, tol: float
) -> PoseSolution:
    """The multi-start of :func:`solve_pose` (no initial guess), on its inputs as bytes."""
    uv = np.frombuffer(image, dtype=float).reshape(n, 2)
    pts = np.frombuffer(points, dtype=float).reshape(n, 3)
    z, table, n_eq = uv.T, projection_table(pts, focal_length), uv.size
    rotated = np.einsum("kij,nj->kni", _CUBE_MATRICES, pts)  # R_k p_i, (24, N, 3)
    t = translations_for_rotations(uv, rotated, focal_length)
    starts = np.concatenate([t, _CUBE_ANGLES], axis=1)
    poses, conv, its, costs = _levenberg_marquardt(z, table, starts, max_iterations, tol)
    rms_all = np.sqrt(costs / n_eq)
    conv &= np.isfinite(rms_all)
    order = np.where(np.isnan(rms_all), np.inf, rms_all)
    pool = np.flatnonzero(conv) if conv.any() else np.arange(rms_all.size)
    i = int(pool[np.argmin(order[pool])])  # converged first, then the least residual; ties: first
    return PoseSolution(_canonical(poses[i]), bool(conv[i]), int(its[i]), float(rms_all[i]))
