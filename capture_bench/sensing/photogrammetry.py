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

The solver of many images (warm and cold), the batched cold multi-start and the damped
Levenberg-Marquardt rounds share the projection table and every helper; split, each half would
import the other's internals.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.row_products import row_stable_matmul
from capture_bench.sim.rotations import matrix_to_euler

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


_POSE_MINOR_ROWS = 128  # from how many poses the projection works pose-minor

# Pose features as products of three entries of (cos x, sin x, cos y, sin y, cos z, sin z, t, 1):
# (a_x[i] a_y[j] a_z[l]) for a_k = (cos, sin, 1) of theta_k, then (t_x, t_y, t_z, 1) times 1 * 1.
_FEATURE_FACTORS = np.array(
    [(i, j, k) for i in (0, 1, 9) for j in (2, 3, 9) for k in (4, 5, 9)]
    + [(6, 9, 9), (7, 9, 9), (8, 9, 9), (9, 9, 9)]
)


def pose_features(poses: FloatArray) -> FloatArray:
    """The 31 pose features ``(27 angle products, t, 1)`` of poses (K, 6) -> (K, 31).

    Feature ``9 i + 3 j + l`` is ``(a_x[i] * a_y[j]) * a_z[l]`` (the order of
    ``_FEATURE_FACTORS``); for many poses computed pose-minor, so that every operation runs over
    all of them (the same products, the same result).
    """
    k = poses.shape[0]
    cos_sin = np.exp(1j * poses[:, 3:]).view(float)  # (cos, sin) of each angle, (K, 6)
    if k < _POSE_MINOR_ROWS:  # few poses: fewer numpy calls beat longer inner loops
        src = np.concatenate((cos_sin, poses[:, :3], np.ones((k, 1))), axis=1)
        factors = src[:, _FEATURE_FACTORS]  # (K, 31, 3)
        return factors[:, :, 0] * factors[:, :, 1] * factors[:, :, 2]
    a = np.ones((3, 3, k))  # a[axis, (cos, sin, 1), pose]
    a[:, :2] = cos_sin.T.reshape(3, 2, k)
    out = np.empty((POSE_FEATURES, k))
    xy = a[0][:, None] * a[1][None]  # (3, 3, K)
    np.multiply(xy[:, :, None], a[2][None, None], out=out[:27].reshape(3, 3, 3, k))
    out[27:30] = poses[:, :3].T
    out[30] = 1.0
    return np.ascontiguousarray(out.T)


def _table_products(
    features: FloatArray, table: FloatArray, alone: NDArray[np.bool_] | None
) -> FloatArray:
    """``features @ table.T`` (K, 7 * 3 * N), a matrix-vector product for the rows ``alone``.

    BLAS rounds a matrix-vector product differently from a matrix-matrix one, and numpy takes
    the former for a single row; a row of a matrix-matrix product comes out the same whatever
    the other rows (`row_stable_matmul`: always an
    even number of them, a lone row twice). None: one product for all K rows, as numpy takes it.
    """
    k = features.shape[0]
    if alone is None:
        return features @ table.T
    n_alone = int(np.count_nonzero(alone))
    if n_alone == 0:
        return row_stable_matmul(features, table.T)
    if n_alone == k:
        return (features[:, None, :] @ table.T)[:, 0]  # a stack of matrix-vector products
    g = np.empty((k, table.shape[0]))
    g[alone] = (features[alone, None, :] @ table.T)[:, 0]
    g[~alone] = row_stable_matmul(features[~alone], table.T)
    return g


def project_poses(
    poses: FloatArray,
    table: FloatArray,
    image: FloatArray | float = 0.0,
    alone: NDArray[np.bool_] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Eqs. 1-2, the residual against an image and the analytic Jacobian, for K poses at once.

    Args:
        poses: (K, 6) poses (x_To, y_To, z_To, theta_x, theta_y, theta_z), metres and radians.
        table: `projection_table` of the feature points.
        image: measured image points, ``[..., 0, :]`` the x_m and ``[..., 1, :]`` the z_m of each
            point, metres: (2, N) for every pose, or (K, 2, N) one per pose; 0 gives the image
            points themselves.
        alone: (K,) which poses to evaluate as a call with that pose alone would (a
            matrix-vector product; the others as rows of a matrix-matrix product, each the same
            whatever the other rows). None: one product for all K poses, so that a single pose
            gets the matrix-vector one.

    Returns:
        ``rj`` (K, 7, 2, N): ``rj[k, 0, c, n] = h[k, c, n] - image[(k,) c, n]`` with h the image
        points (c = 0: x_m, c = 1: z_m) and ``rj[k, 1 + j] = dh[k] / dpose_j``;
        ``depth`` (K, N): ``y_C - f`` per point, metres.
    """
    k = poses.shape[0]
    g = _table_products(pose_features(poses), table, alone)
    if k < _POSE_MINOR_ROWS:  # few poses: fewer numpy calls beat longer inner loops
        g = g.reshape(k, N_QUANTITIES, 3, -1)
        depth = g[:, 0, 2]
        g = g * (1.0 / depth)[:, None, None, :]  # eq. 2 and its quotient rule share 1 / (y_C - f)
        h = g[:, 0, :2]
        rj = g[:, :, :2] - h[:, None] * g[:, :, 2:]  # quotient rule; row 0 comes out as 0
        rj[:, 0] = h - image
        return rj, depth
    n = g.shape[1] // (N_QUANTITIES * 3)
    # Pose-minor from here on, so that every operation runs over all K poses at once.
    gt = np.ascontiguousarray(g.T).reshape(N_QUANTITIES, 3, n, k)
    depth = gt[0, 2].copy()
    gt *= 1.0 / depth  # eq. 2 and its quotient rule share 1 / (y_C - f)
    h = gt[0, :2]
    rjt = np.empty((N_QUANTITIES, 2, n, k))
    np.multiply(h, gt[1:, 2:], out=rjt[1:])  # quotient rule
    np.subtract(gt[1:, :2], rjt[1:], out=rjt[1:])
    img = np.asarray(image)
    image_t = img.transpose(1, 2, 0) if img.ndim == 3 else img[..., None]
    np.subtract(h, image_t, out=rjt[0])
    rj = np.ascontiguousarray(rjt.reshape(-1, k).T).reshape(k, N_QUANTITIES, 2, n)
    return rj, depth.T


def project_pose(
    pose: Sequence[float], table: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Eqs. 1-2 and their analytic Jacobian for one pose, with scalar trigonometry.

    The single-pose twin of `project_poses` (same table, same products), for the EKF's
    per-step h and H where numpy's per-call cost dominates.

    Args:
        pose: (x_To, y_To, z_To, theta_x, theta_y, theta_z), metres and radians, 6 Python floats
            (``array.tolist()``: scalar arithmetic on numpy scalars is slower).
        table: `projection_table` of the feature points.

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
    """One image's result of `solve_poses`.

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


CUBE_MATRICES, CUBE_ANGLES = _cube_rotations()
"""The cold solve's 24 starting rotations: matrices (24, 3, 3) and their Euler angles
``(theta_x, theta_y, theta_z)`` (24, 3), radians (read only; shared by every solve)."""


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


def _alone(solves: NDArray[np.int_] | None, levels: NDArray[np.int_]) -> NDArray[np.bool_]:
    """Per start: is it its solve's only row this round (one start left, trying one lambda)?

    Args:
        solves: (K,) solve labels, or None for one solve.
        levels: (K,) lambdas each start tries this round.
    """
    if solves is None:
        return np.full(levels.size, levels.sum() == 1)
    rows = np.bincount(solves, weights=levels)
    return rows[solves] == 1


MAX_DAMPING = 1e12  # no step at this damping or above is tried: the start sits at a minimum
MAX_SPECULATIVE_LEVELS = 24
_POWERS_OF_TEN = 10.0 ** np.arange(MAX_SPECULATIVE_LEVELS)
# A start in a run of rejections tries its lambdas in these batches, the next batch only if none
# of the previous was accepted: most runs end within two (ends of the batches, in levels).
_LEVEL_BATCHES = (2, 8, MAX_SPECULATIVE_LEVELS)
_BATCHED_ROWS = 256  # from how many rows in a round batches pay


def _trial(
    gram: FloatArray,
    lam: FloatArray,
    base: FloatArray,
    base_cost: FloatArray,
    z: FloatArray,
    alone: NDArray[np.bool_],
    table: FloatArray,
) -> tuple[NDArray[np.bool_], FloatArray, NDArray[np.floating], FloatArray, FloatArray]:
    """One damped step per row, tried: ``(J^T J + lambda (diag(J^T J) + 1e-12)) step = -J^T r``
    from ``base``; accepted when every point stays beyond the lens and the cost does not rise.

    ``gram`` (M, 7, 7) is changed in place (its diagonal damped). Returns accepted (M,), the trial
    poses, the steps, the trials' ``rj`` (M, 7, 2N) and their costs.
    """
    diag = gram.reshape(-1, 49)[:, 8::8]  # the diagonal of J^T J
    diag += lam[:, None] * (diag + 1e-12)
    step, solvable = _solve_damped(gram[:, 1:, 1:], gram[:, 1:, :1])
    trial = base + step
    rj, depth = project_poses(trial, table, z, alone)
    rj = rj.reshape(rj.shape[0], 7, rj.shape[2] * rj.shape[3])
    cost = np.einsum("ij,ij->i", rj[:, 0], rj[:, 0])
    accept = (depth > 0).all(axis=1) & (cost <= base_cost)
    if solvable is not None:
        accept &= solvable
    return accept, trial, step, rj, cost


def _try_levels(
    gram: FloatArray,
    pose: FloatArray,
    cost: FloatArray,
    damping: FloatArray,
    levels: NDArray[np.int_],
    z: FloatArray,
    per_start: bool,
    alone: NDArray[np.bool_],
    table: FloatArray,
) -> tuple[NDArray[np.bool_], FloatArray, NDArray[np.floating], FloatArray, FloatArray, FloatArray]:
    """One round of Levenberg-Marquardt: start i tries ``damping[i] * 10**j`` for j < levels[i].

    The lambdas of a start are tried in order, in batches (``_LEVEL_BATCHES``), until one is
    accepted: every point beyond the lens and the cost not increased. Every operation is
    row-wise, so a step comes out the same whichever other rows are tried with it; ``alone``
    marks the starts whose trial must be evaluated as a matrix-vector product (see
    `project_poses`).

    Args:
        gram: (K, 7, 7) ``[[r.r, (J^T r)^T], [J^T r, J^T J]]`` of each start.
        pose: (K, 6) poses; cost: (K,) their sums of squared residuals.
        damping: (K,) first lambda of each start; levels: (K,) lambdas it may try, >= 1.
        z: the measured image points, (2, N) or, with ``per_start``, (K, 2, N).
        alone: (K,) see above.
        table: `projection_table` of the feature points.

    Returns:
        Per start: accepted, and of its first accepted lambda (else its last one) the trial
        pose, step, ``rj`` (7, 2N) of the trial, its cost and the lambda.
    """
    k = levels.size
    n_eq = 2 * (table.shape[0] // (N_QUANTITIES * 3))
    if (levels == 1).all():  # the common round: one lambda per start, every row its own start
        # (gram is ours to change)
        accept, trial, step, rj_t, cost_t = _trial(gram, damping, pose, cost, z, alone, table)
        return accept, trial, step, rj_t, cost_t, damping
    pending = np.arange(k)
    low = 0
    # Few rows: numpy's per-call cost dominates, so all the lambdas at once.
    batches = _LEVEL_BATCHES if levels.sum() > _BATCHED_ROWS else (MAX_SPECULATIVE_LEVELS,)
    for high in batches:
        count = np.minimum(levels[pending], high) - low  # >= 1: pending starts have more levels
        owner = np.repeat(pending, count)
        first = np.cumsum(count) - count
        last = first + count - 1
        level = low + np.arange(owner.size) - np.repeat(first, count)
        lam_r = damping[owner] * _POWERS_OF_TEN[level]
        ok, trial_r, step_r, rj_r, cost_r = _trial(
            gram[owner],
            lam_r,
            pose[owner],
            cost[owner],
            z[owner] if per_start else z,
            alone[owner],
            table,
        )
        # Each start's first accepted row, else its last one.
        rows = np.where(ok, np.arange(ok.size), ok.size)
        first_ok = np.minimum.reduceat(rows, first)
        found = first_ok <= last
        row = np.where(found, first_ok, last)
        settled = found | (levels[pending] <= high)
        if low == 0 and settled.all():  # every start settled in the first batch
            return found, trial_r[row], step_r[row], rj_r[row], cost_r[row], lam_r[row]
        if low == 0:
            accept = np.zeros(k, dtype=bool)
            trial, step = np.empty((k, 6)), np.empty((k, 6))
            rj_t, cost_t, lam = np.empty((k, 7, n_eq)), np.empty(k), np.empty(k)
        idx, row = pending[settled], row[settled]
        accept[idx] = found[settled]
        trial[idx], step[idx], rj_t[idx] = trial_r[row], step_r[row], rj_r[row]
        cost_t[idx], lam[idx] = cost_r[row], lam_r[row]
        pending = pending[~settled]
        if pending.size == 0:
            break
        low = high
    return accept, trial, step, rj_t, cost_t, lam


def levenberg_marquardt(
    z: FloatArray,
    table: FloatArray,
    poses0: FloatArray,
    max_iterations: int,
    tol: float,
    solves: NDArray[np.int_] | None = None,
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
    the residual do not change within a run. So after a rejection a start tries the next
    lambdas (up to ``MAX_SPECULATIVE_LEVELS``) in one round, in a few batches
    (`_try_levels`), and keeps the first accepted one: the outcome of trying them one by
    one, in one round instead of many.

    Starts may belong to different solves (several images at once): every operation on a start
    is row-wise, so a start's result is bit for bit what it is in a call with only its own solve.
    One thing depends on the other starts of its solve: the products with the projection table
    of a round in which the solve tries one row in all are matrix-vector products (numpy's
    choice for one row), the others matrix-matrix products (`project_poses`); the rows a
    solve would try in a round (its starts' lambdas) decide which, whichever rows are tried.

    Args:
        z: measured image points, ``[..., 0, :]`` the x_m and ``[..., 1, :]`` the z_m of each
            point: (2, N) for every start, or (K, 2, N) one per start.
        table: `projection_table` of the feature points.
        poses0: (K, 6) starting poses.
        max_iterations: iterations per start.
        tol: convergence when the largest step component <= tol * (1 + max |pose|).
        solves: (K,) non-negative labels, equal for the starts of one solve; None: one solve.

    Returns:
        Final poses (K, 6), converged (K,), iterations (K,), cost = sum of squared residuals (K,).
    """
    k = poses0.shape[0]
    poses = np.array(poses0, dtype=float)
    converged = np.zeros(k, dtype=bool)
    iterations = np.zeros(k, dtype=int)
    costs = np.full(k, np.inf)
    per_start = z.ndim == 3
    rj, depth = project_poses(poses, table, z, _alone(solves, np.ones(k, dtype=int)))
    live = np.flatnonzero((depth > 0).all(axis=1))
    if live.size == 0:
        return poses, converged, iterations, costs
    n_eq = z.shape[-2] * z.shape[-1]
    pose = poses[live]
    z_live = z[live] if per_start else z
    solve = None if solves is None else solves[live]
    rj = rj[live].reshape(-1, 7, n_eq)  # rows: the residual (2N), then J^T (6, 2N)
    cost = np.einsum("ij,ij->i", rj[:, 0], rj[:, 0])
    damping = np.full(live.size, 1e-6)
    it = np.ones(live.size, dtype=int)
    levels = np.ones(live.size, dtype=int)  # lambdas each start may try this round
    while True:
        gram = rj @ rj.transpose(0, 2, 1)  # [[r.r, (J^T r)^T], [J^T r, J^T J]], (M, 7, 7)
        accept, trial, step, rj_t, cost_t, lam = _try_levels(
            gram, pose, cost, damping, levels, z_live, per_start, _alone(solve, levels), table
        )
        reject = ~accept
        if not reject.any():  # the common round: every start moves
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
        if reject.any():
            levels = np.where(reject, (damping[:, None] * _POWERS_OF_TEN < MAX_DAMPING).sum(1), 1)
        else:
            levels = np.ones(accept.size, dtype=int)
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
            damping, it, levels = damping[keep], it[keep], levels[keep]
            if per_start:
                z_live = z_live[keep]
            if solve is not None:
                solve = solve[keep]
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


def _checked_inputs(
    images: ArrayLike, feature_points: ArrayLike, guesses: ArrayLike | None
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """images (M, N, 2), feature points (N, 3) and guesses (M, 6) or None as float arrays."""
    uv = np.asarray(images, dtype=float)
    pts = np.asarray(feature_points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or uv.ndim != 3 or uv.shape[1:] != (pts.shape[0], 2):
        raise ValueError(
            f"need images (M, N, 2) and feature_points (N, 3); got images of shape {uv.shape} "
            f"for feature points of shape {pts.shape}"
        )
    if guesses is None:
        return uv, pts, None
    starts = np.asarray(guesses, dtype=float)
    if starts.shape != (uv.shape[0], 6):
        raise ValueError(f"need guesses (M, 6) for {uv.shape[0]} images; got {starts.shape}")
    return uv, pts, starts


def _solve_warm(
    uv: FloatArray,
    pts: FloatArray,
    focal_length: float,
    starts: FloatArray,
    max_iterations: int,
    tol: float,
) -> list[PoseSolution | None]:
    """Levenberg-Marquardt of K images (K, N, 2) from one start each (K, 6), all in one call,
    each image its own solve (bit for bit its result alone): the converged solutions with a
    finite residual (canonical angles), None for the others."""
    k, n_eq = uv.shape[0], uv.shape[1] * uv.shape[2]
    table = projection_table(pts, focal_length)
    z = uv.transpose(0, 2, 1)  # (K, 2, N): the x_m row, then the z_m row
    if k == 1:  # one solve: one image for its start
        z_arg, solves = z[0], None
    else:
        z_arg, solves = z, np.arange(k)
    poses, conv, its, cost = levenberg_marquardt(z_arg, table, starts, max_iterations, tol, solves)
    out: list[PoseSolution | None] = []
    for j in range(k):
        rms = math.sqrt(cost[j] / n_eq)
        ok = conv[j] and math.isfinite(rms)
        out.append(PoseSolution(_canonical(poses[j]), True, int(its[j]), rms) if ok else None)
    return out


def solve_poses(
    images: ArrayLike,
    feature_points: ArrayLike,
    focal_length: float,
    guesses: ArrayLike | None = None,
    max_iterations: int = 50,
    tol: float = 1e-10,
) -> list[PoseSolution]:
    """Pose of the target in the camera frame from each of M images (eqs. 1-2, iterative least
    squares); each image's solution is bit for bit its solution in a call with that image alone.

    An image with a guess is solved by Levenberg-Marquardt from it (warm start; all of them in
    one call, each its own solve); one whose warm start does not converge, and one without a
    guess, by the cold multi-start: from each of the 24 cube rotations with its exact
    least-squares translation, keeping the converged solution of least residual (all of them
    in one call). The cold solutions are memoised by the exact inputs (`clear_solve_cache`).

    Args:
        images: measured ``[x_m, z_m]`` of the feature points per image, metres, (M, N, 2).
        feature_points: the same points in the target frame, metres, shape (N, 3), N >= 3.
        focal_length: f, metres.
        guesses: pose (M, 6) to start each image from, a row of NaN for an image without one;
            None: every image cold.
        max_iterations: Gauss-Newton iterations per start.
        tol: convergence when the largest step component <= tol * (1 + max |pose|).

    Returns:
        M new `PoseSolution` (each the best start, converged or not), the caller's to change.
    """
    uv, pts, starts = _checked_inputs(images, feature_points, guesses)
    f = float(focal_length)
    solutions: list[PoseSolution | None] = [None] * uv.shape[0]
    if starts is not None:
        warm = np.flatnonzero(~np.isnan(starts).all(axis=1))
        if warm.size:
            found = _solve_warm(uv[warm], pts, f, starts[warm], max_iterations, tol)
            for i, solution in zip(warm.tolist(), found, strict=True):
                solutions[i] = solution
    cold = [i for i, solution in enumerate(solutions) if solution is None]
    if cold:
        kept = _cold_solves(uv[cold], pts, f, max_iterations, tol)
        for i, solution in zip(cold, kept, strict=True):
            # the kept one stays untouched
            solutions[i] = dataclasses.replace(solution, pose=solution.pose.copy())
    return [solution for solution in solutions if solution is not None]


# The multi-start is the costliest solve (24 starts: ``benchmarks/bench_photogrammetry_batch.py``,
# the table "The batched cold photogrammetry" of docs/speed.md) and is a pure function of the
# image: an evaluation that runs several agents on one seed images the same first frame each time
# (reset draws it before any agent acts), so it is solved once per process. Keyed by the exact
# bytes, like the projection table; the least recently used is dropped first beyond
# _COLD_SOLVES_KEPT.
_ColdKey = tuple[bytes, bytes, int, float, int, float]
_COLD_SOLVES: OrderedDict[_ColdKey, PoseSolution] = OrderedDict()
_COLD_SOLVES_KEPT = 4096


def _keep_cold(key: _ColdKey, solution: PoseSolution) -> None:
    _COLD_SOLVES[key] = solution
    if len(_COLD_SOLVES) > _COLD_SOLVES_KEPT:
        _COLD_SOLVES.popitem(last=False)


def _cold_solves(
    uv: FloatArray, pts: FloatArray, focal_length: float, max_iterations: int, tol: float
) -> list[PoseSolution]:
    """The cold multi-start of each of M images (M, N, 2), memoised: the images not kept yet
    are solved at once (`_multi_start`, each image's result bit for bit its result alone) and
    kept. A caller that knows the frames its estimators will start from (a recording of many
    episodes) solves them with `solve_poses` first and pays far less an image than one solve a
    call (``benchmarks/bench_photogrammetry_batch.py``; the table "The batched cold
    photogrammetry" of ``docs/speed.md``); the estimators' solves then find them. The solutions
    returned are the kept ones: copy before changing them."""
    n, f = pts.shape[0], focal_length
    keys = [(image.tobytes(), pts.tobytes(), n, f, max_iterations, tol) for image in uv]
    found: list[PoseSolution | None] = [_COLD_SOLVES.get(key) for key in keys]
    for key, kept in zip(keys, found, strict=True):
        if kept is not None:
            _COLD_SOLVES.move_to_end(key)
    todo = [i for i, kept in enumerate(found) if kept is None]
    if todo:
        poses, conv, its, rms = _multi_start(uv[todo], pts, f, max_iterations, tol)
        for j, i in enumerate(todo):
            found[i] = PoseSolution(poses[j].copy(), bool(conv[j]), int(its[j]), float(rms[j]))
            _keep_cold(keys[i], found[i])
    return [solution for solution in found if solution is not None]


def clear_solve_cache() -> None:
    """Forget the memoised cold solves of `solve_poses` (the multi-start without an initial
    guess), so the next one is solved afresh (to time the solve itself, or to check that a
    memoised solution equals a fresh one). The projection tables stay memoised."""
    _COLD_SOLVES.clear()


def solve_cache_size() -> tuple[int, int]:
    """(cold solves memoised now, the most the memo keeps): the memo is a bounded LRU."""
    return len(_COLD_SOLVES), _COLD_SOLVES_KEPT


N_STARTS = len(CUBE_ANGLES)


def _multi_start(
    uv: FloatArray, pts: FloatArray, focal_length: float, max_iterations: int, tol: float
) -> tuple[FloatArray, NDArray[np.bool_], NDArray[np.int_], FloatArray]:
    """The 24-start cold solve of M images (M, N, 2) at once: all M * 24 starts run as one
    Levenberg-Marquardt, each image's starts labelled as one solve, so each image's result is
    bit for bit its result alone.

    Returns:
        Per image: pose (M, 6) with canonical angles, converged (M,), iterations (M,) and
        residual rms (M,) of the converged start of least residual (ties: the first start), or of
        the least residual when none converged.
    """
    m, n_eq = uv.shape[0], uv.shape[1] * uv.shape[2]
    table = projection_table(pts, focal_length)
    rotated = np.einsum("kij,nj->kni", CUBE_MATRICES, pts)  # R_k p_i, (24, N, 3)
    starts = np.empty((m, N_STARTS, 6))
    for i in range(m):  # the image's own least-squares matrix: one lstsq call per image
        starts[i, :, :3] = translations_for_rotations(uv[i], rotated, focal_length)
    starts[:, :, 3:] = CUBE_ANGLES
    z = uv.transpose(0, 2, 1)  # (M, 2, N): the x_m row, then the z_m row
    if m == 1:  # one solve: one image for every start
        z_arg, solves = z[0], None
    else:
        z_arg, solves = np.repeat(z, N_STARTS, axis=0), np.repeat(np.arange(m), N_STARTS)
    poses, conv, its, costs = levenberg_marquardt(
        z_arg, table, starts.reshape(-1, 6), max_iterations, tol, solves
    )
    rms_all = np.sqrt(costs / n_eq).reshape(m, N_STARTS)
    conv = conv.reshape(m, N_STARTS) & np.isfinite(rms_all)
    order = np.where(np.isnan(rms_all), np.inf, rms_all)
    pool = conv | ~conv.any(axis=1, keepdims=True)  # the converged starts, else every start
    best = np.argmin(np.where(pool, order, np.inf), axis=1)  # least residual; ties: the first
    rows = np.arange(m) * N_STARTS + best
    out = np.array([_canonical(pose) for pose in poses[rows]]).reshape(m, 6)
    return out, conv.reshape(-1)[rows], its[rows], rms_all.reshape(-1)[rows]
