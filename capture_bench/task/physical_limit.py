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

Only each chunk's or pass's *first* feasible time matters, so the search (:func:`first_feasible`)
skips the local search wherever :func:`distance_lower_bound` already puts the whole box farther
than ``|epsilon|`` from X_T, and after the first feasible time; it gives exactly what evaluating
every time with :func:`feasible_solutions` would. :func:`physical_limits` runs the search for
many episodes at once (one evaluation per round for all of them); :func:`physical_limit` is its
one-episode case.

With a hold (``capture.hold`` = h s), a capture needs eq. 20 to hold from some entry t_e to
t_e + h; eq. 20 cannot hold before the arrival bound T, so t_e >= T and every capture completes at
or after T + h: the bound is ``T + h`` (:func:`capture_bench.task.episode.episode_bounds`), still
a lower bound. It is attainable where the arm can follow the capture point for h after arriving
(the targets move centimetres per second, the joints far faster), which the oracle shows.

Why one file of ~510 lines: the bound's search, its pruning bound and its brute-force reference
(:func:`feasible_solutions`, the test's definition of the answer) belong together.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from capture_bench.sim.kinematics import (
    L1,
    L2,
    forward_kinematics,
    inverse_kinematics_batch,
    jacobian,
)

FloatArray = NDArray[np.float64]
NEWTON_STEPS = 10
NEAR_BOX = 0.1  # rad
REFINE = 64
REFINE_PASSES = 2
CHUNK = 32
BOUND_MARGIN = 1e-9  # m: rounding allowance of distance_lower_bound


@dataclass(frozen=True)
class PhysicalLimit:
    """The episode's bound.

    Attributes:
        time: earliest feasible capture time, s: the earliest time eq. 20 can hold (the arrival)
            plus the capture's ``hold``; ``inf`` if the target is never reachable in time.
        theta: a joint vector, rad, (3,), whose end-effector is within ``|epsilon|`` of the capture
            point at the arrival (None if inf).
        hold: the scenario's ``capture.hold``, s (0: eq. 20 at one instant, ``time`` the arrival).
    """

    time: float
    theta: FloatArray | None
    hold: float = 0.0

    @property
    def arrival(self) -> float:
        """The earliest time eq. 20 can hold at all, s (``time - hold``; ``inf`` if none)."""
        return self.time - self.hold


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
    box_lo, box_hi, solutions, excess = _box_solutions(
        targets, times, theta0, joint_rate_limits, lower, upper
    )
    inside = excess <= 0.0
    feasible: NDArray[np.bool_] = np.any(inside, axis=1)
    theta = np.zeros((targets.shape[0], 3))
    first = np.argmax(inside, axis=1)
    theta[feasible] = solutions[feasible, first[feasible]]
    near = ~feasible[:, None] & (excess < NEAR_BOX)  # False where NaN
    if np.any(near):
        rows, cols = np.nonzero(near)
        goal = targets[rows]
        q = nearest_in_box(solutions[rows, cols], goal, box_lo[rows], box_hi[rows])
        close = np.linalg.norm(forward_kinematics(q) - goal, axis=1) < np.linalg.norm(tolerance)
        feasible[rows[close]] = True
        theta[rows[close]] = q[close]  # of several columns of one row, the last one's
    return feasible, theta


def _box_solutions(
    targets: FloatArray,
    times: FloatArray,
    theta0: FloatArray,
    joint_rate_limits: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The reachable boxes (N, 3) x 2, the IK solutions (N, 4, 3) and how far each lies outside
    its box (N, 4), rad: the largest excess over the joints, <= 0 inside, NaN where none."""
    box_lo = np.maximum(lower, theta0 - np.outer(times, joint_rate_limits))  # (N, 3)
    box_hi = np.minimum(upper, theta0 + np.outer(times, joint_rate_limits))
    solutions = inverse_kinematics_batch(targets)  # (N, 4, 3), NaN where none
    per_joint = np.maximum(box_lo[:, None] - solutions, solutions - box_hi[:, None])  # (N, 4, 3)
    excess = np.maximum(np.maximum(per_joint[..., 0], per_joint[..., 1]), per_joint[..., 2])
    return box_lo, box_hi, solutions, excess


def first_feasible(
    targets: FloatArray,
    times: FloatArray,
    offsets: NDArray[np.intp],
    theta0: FloatArray,
    joint_rate_limits: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    tolerance: FloatArray,
) -> tuple[NDArray[np.intp], FloatArray]:
    """For consecutive segments of rows, the first row :func:`feasible_solutions` calls feasible.

    Exactly what ``feasible_solutions`` gives (the same row, the same theta), with a fraction of
    its work: only the rows before a segment's first feasible one matter, and a near solution
    needs the local search only when :func:`distance_lower_bound` does not already put the box
    out of tolerance. The local searches then go in rounds, the earliest remaining candidate row
    of every segment per round (:func:`nearest_in_box` gives a row the same result in any batch).

    Args:
        targets, times, theta0 ... tolerance: as :func:`feasible_solutions`.
        offsets: segment s is rows ``offsets[s]:offsets[s + 1]`` (S + 1,), none empty.

    Returns:
        ``(first (S,), theta (S, 3))``: the first feasible row (global index; ``N`` where
        none) and its joint vector (meaningful where one is feasible).
    """
    n = targets.shape[0]
    box_lo, box_hi, solutions, excess = _box_solutions(
        targets, times, theta0, joint_rate_limits, lower, upper
    )
    inside = excess <= 0.0
    exact = inside.any(axis=1)
    segment = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))  # (N,)
    index = np.arange(n)
    first = np.minimum.reduceat(np.where(exact, index, n), offsets[:-1])  # (S,)
    theta = np.zeros((offsets.size - 1, 3))
    found = first < n
    theta[found] = solutions[first[found], np.argmax(inside[first[found]], axis=1)]
    # Near solutions of the rows before their segment's first exactly feasible one.
    near = (index < first[segment])[:, None] & (excess < NEAR_BOX)
    rows, cols = np.nonzero(near)  # ordered by row, then column
    if rows.size == 0:
        return first, theta
    radius = float(np.linalg.norm(tolerance))
    enough = radius + BOUND_MARGIN
    bound = distance_lower_bound(targets[rows], solutions[rows], box_lo[rows], box_hi[rows], enough)
    keep = bound < enough  # the others are certainly not close
    rows, cols = rows[keep], cols[keep]
    while rows.size:
        rows, cols, rows_segment = _live(rows, cols, segment, first)
        if rows.size == 0:
            break
        # Every segment's earliest candidate row (all its columns), searched together.
        group = _group_starts(rows_segment)
        now = rows == rows[group][np.cumsum(group) - 1]
        r, c = rows[now], cols[now]
        goal = targets[r]
        q = nearest_in_box(solutions[r, c], goal, box_lo[r], box_hi[r])
        close = np.linalg.norm(forward_kinematics(q) - goal, axis=1) < radius
        hit = r[close]
        first[segment[hit]] = hit
        theta[segment[hit]] = q[close]  # of several columns of one row, the last one's
        rows, cols = rows[~now], cols[~now]
    return first, theta


def _live(
    rows: NDArray[np.intp],
    cols: NDArray[np.intp],
    segment: NDArray[np.intp],
    first: NDArray[np.intp],
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """The (row, column) pairs before their segment's first feasible row, and their segments."""
    rows_segment = segment[rows]
    live = rows < first[rows_segment]
    return rows[live], cols[live], rows_segment[live]


def _group_starts(keys: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Where a run of equal ``keys`` (sorted) begins, (M,) with M >= 1."""
    starts = np.empty(keys.size, bool)
    starts[0] = True
    np.not_equal(keys[1:], keys[:-1], out=starts[1:])
    return starts


def distance_lower_bound(
    goal: FloatArray, solutions: FloatArray, lo: FloatArray, hi: FloatArray, enough: float
) -> FloatArray:
    """A lower bound on ``min ||f(theta) - goal||`` over theta in the box [lo, hi], m, (M,).

    With ``goal = (rho cos b, rho sin b, z)`` and ``f(theta) = (r cos t1, r sin t1, z(t2, t3))``:

        ||f - goal||^2 = r^2 + rho^2 - 2 r rho cos(t1 - b) + (z(t2, t3) - z)^2

    so ``||f - goal||`` is at least

    * (radial) ``| ||goal|| - ||f|| |`` where ``||f||^2 = l1^2 + l2^2 + 2 l1 l2 sin t3``;
    * (azimuth) ``rho |sin(t1 - b)|`` (the minimum over r), least over [lo1, hi1];
    * (planar) the distance from ``(+-rho, z)`` to the planar arm's reach of ``(r, z)`` over the
      (t2, t3) rectangle (``(|r| - rho)^2 + (z(t2, t3) - z)^2``). Where the planar Jacobian
      (det = -l1 l2 cos t3) is regular, that is 0 if one of the IK ``solutions`` (M, 4, 3)
      has its (t2, t3) in the rectangle, else it is attained on the rectangle's edges, whose
      images are circular arcs between the corners' images: t2 fixed, radius l2 about the
      elbow; t3 fixed, radius ``||f||`` about joint 2 (the arm turns rigidly). The distance to
      an arc is the distance to its circle where the point lies in the arc's sector (or where
      that is not tested: a circle's distance never exceeds its arc's), else to its ends.

    The radial bound comes first; rows where it reaches ``enough`` (m) get no other. Elsewhere
    the bound is the largest of the three (0 where unsure). Rounding: see ``BOUND_MARGIN``.
    """
    lo2, hi2, lo3, hi3 = lo[:, 1], hi[:, 1], lo[:, 2], hi[:, 2]
    # The planar arcs and the radial bound need sin t3 monotonic and cos t3 > 0 inside.
    regular = (lo3 >= -np.pi / 2) & (hi3 <= np.pi / 2)
    distance = np.sqrt(np.einsum("mi,mi->m", goal, goal))  # ||goal||, from joint 2
    s3 = np.sin(np.stack([lo3, hi3]))  # (2, M)
    reach = np.sqrt(L1 * L1 + L2 * L2 + 2.0 * L1 * L2 * s3)  # ||f|| at t3 = lo3, hi3
    radial = np.maximum(np.maximum(reach[0] - distance, distance - reach[1]), 0.0)
    bound = np.where(regular, radial, 0.0)
    rest = np.flatnonzero(bound < enough)
    if rest.size == 0:
        return bound
    goal, solutions, lo, hi = goal[rest], solutions[rest], lo[rest], hi[rest]
    lo2, hi2, lo3, hi3 = lo2[rest], hi2[rest], lo3[rest], hi3[rest]
    distance, s3, reach = distance[rest], s3[:, rest], reach[:, rest]
    rho = np.hypot(goal[:, 0], goal[:, 1])
    z = goal[:, 2]
    # Azimuth: [lo1 - b, hi1 - b] holds a multiple of pi, or |sin| is least at one of its ends.
    u0 = lo[:, 0] - np.arctan2(goal[:, 1], goal[:, 0])
    u1 = u0 + (hi[:, 0] - lo[:, 0])
    spans_zero = np.floor(u1 / np.pi) >= np.ceil(u0 / np.pi)
    azimuth = np.where(spans_zero, 0.0, rho * np.minimum(np.abs(np.sin(u0)), np.abs(np.sin(u1))))
    # Planar: the point (sign * rho, z) for sign = +-1 (axis 0 of the (2, ...) arrays below).
    t2 = np.stack([lo2, hi2])
    c2, s2, c3 = np.cos(t2), np.sin(t2), np.cos(np.stack([lo3, hi3]))  # (2, M)
    elbow_r, elbow_z = L1 * c2[:, None], L1 * s2[:, None]  # (t2, 1, M)
    # Forearm direction (sin(t2 + t3), -cos(t2 + t3)), indexed (t2, t3, M).
    fore_r = s2[:, None] * c3[None] + c2[:, None] * s3[None]
    fore_z = s2[:, None] * s3[None] - c2[:, None] * c3[None]
    corner_r, corner_z = elbow_r + L2 * fore_r, elbow_z + L2 * fore_z  # (t2, t3, M)
    point_r = np.stack([rho, -rho])  # (sign, M)
    dz = z - corner_z  # (t2, t3, M)
    dr = point_r[:, None, None] - corner_r  # (sign, t2, t3, M)
    planar_sq = (dr * dr + dz * dz).min(axis=(0, 1, 2))
    # t2 fixed: circle of radius l2 about the elbow; sector between the forearm directions.
    vr, vz = point_r[:, None] - elbow_r[None, :, 0], z - elbow_z[:, 0]  # (sign, t2, M)
    small = (hi3 - lo3) <= np.pi
    faces = ~small | (
        (fore_r[:, 0] * vz - fore_z[:, 0] * vr >= 0.0)
        & (vr * fore_z[:, 1] - vz * fore_r[:, 1] >= 0.0)
    )
    arc = np.where(faces, np.abs(np.hypot(vr, vz) - L2), np.inf).min(axis=(0, 1))
    # t3 fixed: circle of radius reach(t3) about joint 2; sector between the corners t2 = lo2, hi2.
    small = (hi2 - lo2) <= np.pi
    faces = ~small | (
        (corner_r[0] * z - corner_z[0] * point_r[:, None] >= 0.0)
        & (point_r[:, None] * corner_z[1] - z * corner_r[1] >= 0.0)
    )  # (sign, t3, M)
    arc = np.minimum(arc, np.where(faces, np.abs(distance - reach), np.inf).min(axis=(0, 1)))
    planar = np.minimum(np.sqrt(planar_sq), arc)
    t23 = solutions[:, :, 1:]
    reached = np.all((t23 >= lo[:, None, 1:]) & (t23 <= hi[:, None, 1:]), axis=2).any(axis=1)
    # IK angles are wrapped to [-pi, pi): the box must be too for ``reached`` to be complete.
    wrapped = regular[rest] & (lo2 >= -np.pi) & (hi2 < np.pi)
    planar = np.where(wrapped & ~reached, planar, 0.0)
    bound[rest] = np.maximum(np.maximum(azimuth, planar), bound[rest])
    return bound


def nearest_in_box(
    start: FloatArray,
    goal: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    iterations: int = NEWTON_STEPS,
) -> FloatArray:
    """Joint vectors in the box [lo, hi] whose end-effector is nearest ``goal`` (local search).

    Active-set projected Gauss-Newton on ``||f(theta) - goal||^2``: a joint on a bound whose
    gradient points out of the box is held there, the others take the least-squares step. Each
    row stops on its own (after the step that moved it by less than 1e-10 rad, or after
    ``iterations`` steps), so a row's result does not depend on the other rows of the batch:
    the rows of many episodes can be searched together with the same results as one by one.

    Args:
        start: initial joint vectors, rad, (M, 3).
        goal: target points, global, m, (M, 3).
        lo, hi: box bounds, rad, (M, 3).
    """
    q = np.clip(start, lo, hi)
    rows: NDArray[np.intp] | None = None  # the rows still moving; None: all of them
    for _ in range(iterations):
        if rows is None:
            q_r, goal_r, lo_r, hi_r = q, goal, lo, hi
        else:
            q_r, goal_r, lo_r, hi_r = q[rows], goal[rows], lo[rows], hi[rows]
        residual = goal_r - forward_kinematics(q_r)  # (M, 3)
        jac = jacobian(q_r)  # (M, 3, 3)
        ascent = np.einsum("mij,mi->mj", jac, residual)  # J^T r: where moving theta helps
        held = ((q_r <= lo_r) & (ascent < 0.0)) | ((q_r >= hi_r) & (ascent > 0.0))
        # Least squares over the free joints: (Jf^T Jf + diag(held)) step = Jf^T r, where Jf is
        # J with the held joints' columns zeroed (their step is then exactly 0).
        free_jac = jac * ~held[:, None, :]
        normal = np.einsum("mki,mkj->mij", free_jac, free_jac) + held[:, :, None] * np.eye(3)
        rhs = np.einsum("mij,mi->mj", free_jac, residual)
        step = np.linalg.solve(normal, rhs[..., None])[..., 0]
        moving = np.max(np.abs(step), axis=1) >= 1e-10  # NaN (never here): stops
        if rows is None:
            q = np.clip(q + step, lo, hi)
            if moving.all():
                continue
            rows = np.flatnonzero(moving)
        else:
            q[rows] = np.clip(q_r + step, lo_r, hi_r)
            rows = rows[moving]
        if rows.size == 0:
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

    One episode of :func:`physical_limits` (the same implementation).

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
    (limit,) = physical_limits(
        [target_position],
        theta0,
        joint_rate_limits,
        lower,
        upper,
        tolerance,
        horizons=[horizon],
        period=period,
        travel_times=[travel_time],
    )
    return limit


def physical_limits(
    target_positions: Sequence[Callable[[FloatArray], FloatArray]],
    theta0: FloatArray,
    joint_rate_limits: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    tolerance: FloatArray,
    horizons: Sequence[float],
    period: float,
    travel_times: Sequence[Callable[[FloatArray], FloatArray] | None] | None = None,
) -> list[PhysicalLimit]:
    """:func:`physical_limit` for G episodes of one arm at once (a vectorised environment).

    Every episode follows the search of the module docstring (grid chunks of ``CHUNK`` times,
    then ``REFINE_PASSES`` refine passes), but each round evaluates the next chunk or pass of
    every unfinished episode in one :func:`first_feasible` call (the target positions and
    travel times are asked of each episode's callables). Its rows are independent of one another
    (:func:`nearest_in_box` stops row by row), so episode g's result is exactly that of
    ``physical_limit(target_positions[g], ..., horizons[g], period, travel_times[g])``, which is
    this function with G = 1.

    Args:
        target_positions: per episode, X_T(t) for times of shape (N,) -> (N, 3), global, m.
        theta0, joint_rate_limits, lower, upper, tolerance: as :func:`physical_limit`, shared.
        horizons: per episode, the episode limit, s.
        period: grid spacing (the nominal control period t_s), s, shared.
        travel_times: per episode, as :func:`physical_limit`'s ``travel_time`` (None entries:
            t itself); None: t itself for every episode.

    Returns:
        One :class:`PhysicalLimit` per episode, in order.
    """
    count = len(target_positions)
    if len(horizons) != count:
        raise ValueError(f"horizons has {len(horizons)} entries for {count} target_positions")
    travels = [None] * count if travel_times is None else list(travel_times)
    if len(travels) != count:
        raise ValueError(f"travel_times has {len(travels)} entries for {count} target_positions")
    args = (
        np.asarray(theta0, float),
        np.asarray(joint_rate_limits, float),
        np.asarray(lower, float),
        np.asarray(upper, float),
        np.asarray(tolerance, float),
    )
    # Each episode's search: on the grid (pass -1) from index ``start``, then refine passes
    # 0 .. REFINE_PASSES - 1 of (t_lo, t_hi], ``best`` the joint vector at t_hi.
    n_grid = np.array([int(np.floor(h / period + 1e-9)) + 1 for h in horizons], dtype=np.intp)
    start = np.zeros(count, dtype=np.intp)
    stage = np.full(count, -1)
    t_lo, t_hi, best = np.zeros(count), np.zeros(count), np.zeros((count, 3))
    time = np.full(count, np.inf)  # the result, where ``done``
    done = n_grid <= 0
    grid_steps = np.arange(CHUNK)
    while not done.all():
        grid = np.flatnonzero(~done & (stage < 0))
        fine = np.flatnonzero(~done & (stage >= 0))
        # The grid chunk times of ``grid`` (as np.arange(start, stop) * period), then the
        # refine times of ``fine`` (as np.linspace(t_lo, t_hi, REFINE + 1)[1:]), flattened.
        index = start[grid, None] + grid_steps
        valid = index < n_grid[grid, None]
        lengths = np.concatenate((valid.sum(axis=1), np.full(fine.size, REFINE)))
        fine_times = refine_times(t_lo[fine], t_hi[fine])
        times = np.concatenate((index[valid].astype(np.float64) * period, fine_times.ravel()))
        offsets = np.zeros(lengths.size + 1, dtype=np.intp)
        np.cumsum(lengths, out=offsets[1:])
        episodes = np.concatenate((grid, fine)).tolist()
        targets, moved = [], times.copy()
        for i, g in enumerate(episodes):
            part = slice(offsets[i], offsets[i + 1])
            targets.append(target_positions[g](times[part]))
            travel = travels[g]
            if travel is not None:
                moved[part] = travel(times[part])
        first, theta = first_feasible(np.concatenate(targets), moved, offsets, *args)
        found = first < times.size
        local = first - offsets[:-1]
        at = np.minimum(first, times.size - 1)
        # Grid: nothing feasible -> next chunk (or inf past the horizon); at t = 0 -> 0;
        # else refine the period before.
        on_grid = np.arange(grid.size)
        missed = grid[~found[on_grid]]
        start[missed] += CHUNK
        done[missed[start[missed] >= n_grid[missed]]] = True
        hit = on_grid[found[on_grid]]
        zero = hit[start[grid[hit]] + local[hit] == 0]
        time[grid[zero]], best[grid[zero]], done[grid[zero]] = 0.0, theta[zero], True
        hit = hit[start[grid[hit]] + local[hit] != 0]
        g = grid[hit]
        t_hi[g] = times[at[hit]]
        t_lo[g] = t_hi[g] - period
        best[g] = theta[hit]
        stage[g] = 0
        # Refine: the first feasible time (the last, t_hi, is known to be); the next pass.
        on_fine = np.arange(grid.size, grid.size + fine.size)
        hit = on_fine[found[on_fine]]
        g = fine[found[on_fine]]
        t_lo[g] = np.where(local[hit] > 0, times[np.maximum(at[hit] - 1, 0)], t_lo[g])
        t_hi[g] = times[at[hit]]
        best[g] = theta[hit]
        stage[fine] += 1
        over = fine[stage[fine] == REFINE_PASSES]
        time[over], done[over] = t_hi[over], True
    return [
        PhysicalLimit(float(time[g]), best[g].copy() if np.isfinite(time[g]) else None)
        for g in range(count)
    ]


def refine_times(t_lo: FloatArray, t_hi: FloatArray) -> FloatArray:
    """``np.linspace(t_lo[i], t_hi[i], REFINE + 1)[1:]`` for every i, bit for bit, (I, REFINE)."""
    delta = (t_hi - t_lo)[:, None]
    steps = np.arange(1, REFINE + 1, dtype=np.float64)
    step = delta / REFINE
    times = np.where(step == 0.0, steps / REFINE * delta, steps * step)  # as np.linspace
    times += t_lo[:, None]
    times[:, -1] = t_hi
    return times
