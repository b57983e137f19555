"""The physical limit of an episode: a lower bound on any agent's capture time (DESIGN.md).

Joints are independent velocity-limited integrators, so the joint vectors reachable by time t form
the box ``|theta_i - theta_i(0)| <= theta_dot_max_i t`` intersected with the joint limits. The
earliest time at which the true capture point X_T(t) has an inverse-kinematics solution inside
that box (within the capture tolerance epsilon, component-wise as in eq. 20) bounds every agent's
capture time from below.

How it is computed:

1. On the grid ``t_k = k * period`` up to the horizon, every closed-form IK solution of X_T(t_k)
   is tested against the box (exact). Where none lies inside but one lies within
   `near_box` rad of it, the tolerance is used: from the solution clipped to the box,
   `nearest_in_box` (active-set projected Gauss-Newton) finds the box's joint vector whose
   end-effector is nearest X_T, and the point counts as feasible when that distance is below
   ``|epsilon|`` (the radius of the sphere around eq. 20's tolerance cube). Using the sphere, not
   the cube, keeps the bound a *lower* bound: anything eq. 20 accepts is inside the sphere. (Inside
   the joint limits the end-effector moves at least ``MIN_REACH`` ~0.07 m per rad of any joint,
   so a solution further than ``2 |epsilon| / MIN_REACH`` outside the box, or ``NEAR_BOX`` =
   0.1 rad where that is less, is far from anything in it.)
2. Between the last infeasible and the first feasible grid time, the interval is searched
   ``REFINE_PASSES`` times with ``REFINE`` evenly spaced times, which finds the onset to
   ``period / REFINE**REFINE_PASSES`` (12 microseconds at t_s = 0.05 s). The
   bound is exact to well below the control period, assuming feasibility does not switch on and
   off again inside one period (the box grows monotonically; the target moves mm per period).

Only each chunk's or pass's *first* feasible time matters, so the search (`first_feasible`)
skips the local search wherever `distance_lower_bound` already puts the whole box farther
than ``|epsilon|`` from X_T, and after the first feasible time; it gives exactly what evaluating
every time with `feasible_solutions` would. `physical_limits` runs the search for
many episodes at once (one evaluation per round for all of them); `physical_limit` is its
one-episode case.

The capture envelope (``capture.hold`` = h s, ``capture.v_max`` m/s): a capture needs, from some
entry t_e through t_e + h, the end-effector inside eq. 20's box *and* its instantaneous velocity
relative to the capture point within v_max. The joints have no acceleration limit: an arm that
arrives at full rate can take the rates that follow the target at once, so the speed bound adds
nothing at the arrival as such. The envelope's bound is ``t_e + h`` for the earliest entry t_e
from which the arm can be in the envelope at every instant of ``[t_e, t_e + h]``, which at an
instant t needs (`envelope_feasible`):

* *eq. 20's box*: a joint vector in the reachable box at t whose end-effector is inside eq. 20's
  box about X_T(t), decided exactly (`cube_reachable`: joint 1 turns the arm's plane, in
  which eq. 20's box is a rectangle and the reach of joints 2 and 3 a region bounded by four
  circular arcs); the box itself, not the sphere about it, so where the sphere reaches the
  target before the box's faces do, and where the target leaves the arm's reach during the
  hold, the entry is later;
* *the tracking*, with v_max: joint rates within their limits that move the end-effector within
  v_max of Xdot_T(t), at the IK solutions of X_T(t) (`least_relative_speeds`, exact over
  the rate box; the Jacobian is the capture point's own, where the arm within epsilon of it
  has one a little different). The joints outrun the shipped targets (cm/s) so far that this
  never binds there (1,500 drawn trajectories, 10 mm, 0.3 s: no bound changes with v_max = 50
  mm/s); a target faster than the joints can follow does. Without v_max no instant's velocity
  is bounded, and the box alone is tested.

`held_arrivals` tests both on a grid of ``HOLD_SAMPLES`` times per period over each
candidate hold, from the arrival T of the search above (eq. 20's box lies inside the sphere, so
t_e >= T), and refines the onset after a failing time to ``period / (HOLD_SAMPLES REFINE)``.
Each condition is necessary, and a stretch shorter than the grid's step where one fails can only
go unseen, so the bound stays a lower bound. It is attained where the arm, once in the envelope,
can follow the capture point: the rates ``J^{-1} Xdot_T`` that follow it exactly are at most
0.54 of the limits over the holds of 40 validation episodes of each shipped motion, and the
oracle (``capture_bench/agents/oracle.py``) captures within a control period of it. With neither
a hold nor a speed bound the bound is T, the search above alone.

Why one file: the bound's search, its pruning bound and its brute-force reference
(`feasible_solutions`, the test's definition of the answer), and the envelope's tests on
top of them, belong together.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from capture_bench.sim.kinematics import (
    L1,
    L2,
    forward_kinematics,
    inverse_kinematics,
    jacobian,
)

FloatArray = NDArray[np.float64]
NEWTON_STEPS = 10
NEAR_BOX = 0.1  # rad: the least of near_box()
MIN_REACH = 0.07  # m/rad: the least the end-effector moves per rad of a joint (joint limits)
REFINE = 64
REFINE_PASSES = 2
CHUNK = 32
BOUND_MARGIN = 1e-9  # m: rounding allowance of distance_lower_bound
HOLD_SAMPLES = 8  # per control period: the times of a hold at which the envelope is tested
#: The faces of the joint-rate box (`least_relative_speeds`): each joint free (0) or at
#: its lower (-1) or upper (+1) rate limit, every combination, (27, 3).
RATE_FACES = np.array(np.meshgrid(*[[-1, 0, 1]] * 3, indexing="ij")).reshape(3, -1).T


@dataclass(frozen=True)
class PhysicalLimit:
    """The episode's bound.

    Attributes:
        time: earliest feasible capture time, s: the earliest time eq. 20 can hold (the arrival;
            with the capture envelope, the earliest entry from which the envelope can be held)
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
    near = ~feasible[:, None] & (excess < near_box(tolerance))  # False where NaN
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
    solutions = inverse_kinematics(targets)  # (N, 4, 3), NaN where none
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
    """For consecutive segments of rows, the first row `feasible_solutions` calls feasible.

    Exactly what ``feasible_solutions`` gives (the same row, the same theta), with a fraction of
    its work: only the rows before a segment's first feasible one matter, and a near solution
    needs the local search only when `distance_lower_bound` does not already put the box
    out of tolerance. The local searches then go in rounds, the earliest remaining candidate row
    of every segment per round (`nearest_in_box` gives a row the same result in any batch).

    Args:
        targets, times, theta0 ... tolerance: as `feasible_solutions`.
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
    near = (index < first[segment])[:, None] & (excess < near_box(tolerance))
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


def near_box(tolerance: FloatArray) -> float:
    """How far outside the reachable box (rad, the largest excess over the joints) an IK solution
    may lie and still be searched for a joint vector in the box within the tolerance:
    ``max(NEAR_BOX, 2 |epsilon| / MIN_REACH)``. A joint vector that far outside moves the
    end-effector by more than ``|epsilon|`` coming back, with a factor 2 to spare."""
    return max(NEAR_BOX, 2.0 * float(np.linalg.norm(tolerance)) / MIN_REACH)


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
    *,
    hold: float = 0.0,
    v_max: float | None = None,
    target_velocity: Callable[[FloatArray], FloatArray] | None = None,
) -> PhysicalLimit:
    """The earliest time the true capture point can be reached, and with ``hold`` or ``v_max``
    held in the capture envelope, plus the hold (see module docstring).

    One episode of `physical_limits` (the same implementation).

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
        hold: ``capture.hold``, s: how long the envelope must hold (0: one instant).
        v_max: ``capture.v_max``, m/s (None: no speed bound).
        target_velocity: Xdot_T(t) for times (N,) -> (N, 3), global, m/s; needed with v_max.

    Returns:
        The `PhysicalLimit`: ``time`` the arrival plus ``hold``, ``hold`` as given.
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
        hold=hold,
        v_max=v_max,
        target_velocities=None if target_velocity is None else [target_velocity],
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
    *,
    hold: float = 0.0,
    v_max: float | None = None,
    target_velocities: Sequence[Callable[[FloatArray], FloatArray]] | None = None,
) -> list[PhysicalLimit]:
    """`physical_limit` for G episodes of one arm at once (a vectorised environment).

    Every episode follows the search of the module docstring (grid chunks of ``CHUNK`` times,
    then ``REFINE_PASSES`` refine passes), but each round evaluates the next chunk or pass of
    every unfinished episode in one `first_feasible` call (the target positions and
    travel times are asked of each episode's callables). Its rows are independent of one another
    (`nearest_in_box` stops row by row), so episode g's result is exactly that of
    ``physical_limit(target_positions[g], ..., horizons[g], period, travel_times[g])``, which is
    this function with G = 1.

    Args:
        target_positions: per episode, X_T(t) for times of shape (N,) -> (N, 3), global, m.
        theta0, joint_rate_limits, lower, upper, tolerance: as `physical_limit`, shared.
        horizons: per episode, the episode limit, s.
        period: grid spacing (the nominal control period t_s), s, shared.
        travel_times: per episode, as `physical_limit`'s ``travel_time`` (None entries:
            t itself); None: t itself for every episode.
        hold, v_max: the capture envelope, as `physical_limit`'s, shared.
        target_velocities: per episode, Xdot_T(t) for times (N,) -> (N, 3), global, m/s;
            needed with ``v_max``.

    Returns:
        One `PhysicalLimit` per episode, in order: ``time`` the arrival (the search above,
        then, with a hold or a speed bound, `held_arrivals`) plus ``hold``.
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
    if hold == 0.0 and v_max is None:
        return [
            PhysicalLimit(float(time[g]), best[g].copy() if np.isfinite(time[g]) else None)
            for g in range(count)
        ]
    if v_max is not None and (target_velocities is None or len(target_velocities) != count):
        raise ValueError("v_max needs target_velocities, one per target_positions")
    time, best = held_arrivals(
        time,
        best,
        target_positions,
        target_velocities,
        *args,
        horizons=horizons,
        period=period,
        travel_times=travels,
        hold=hold,
        v_max=v_max,
    )
    return [
        PhysicalLimit(float(time[g]) + hold, best[g].copy(), hold)
        if np.isfinite(time[g])
        else PhysicalLimit(np.inf, None, hold)
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


def least_relative_speeds(
    jac: FloatArray, target_velocity: FloatArray, joint_rate_limits: FloatArray
) -> FloatArray:
    """The least ``|J omega - Xdot_T|`` over joint rates ``|omega_i| <= theta_dot_max_i``, m/s,
    (M,): how close to the capture point's velocity the end-effector can move at each row's
    joint vector.

    Exact: 0 where the rates ``J^{-1} Xdot_T`` that match it lie in the box; else the least of
    the convex quadratic lies inside one face of the box (each joint free or at one of its rate
    limits, `RATE_FACES`), where it is the least squares over the free joints; the answer
    is the smallest residual of the faces' least squares that lie in their face.

    Args:
        jac: J(theta), (M, 3, 3).
        target_velocity: Xdot_T, global, m/s, (M, 3).
        joint_rate_limits: theta_dot_max, rad/s, (3,).
    """
    out = np.zeros(jac.shape[0])
    matching = np.einsum("mij,mj->mi", np.linalg.pinv(jac), target_velocity)
    rows = np.flatnonzero(~np.all(np.abs(matching) <= joint_rate_limits, axis=1))
    if rows.size == 0:
        return out
    free = RATE_FACES == 0  # (F, 3)
    fixed = RATE_FACES * joint_rate_limits  # (F, 3), 0 where free
    jac_r, velocity = jac[rows][:, None], target_velocity[rows][:, None]  # (R, 1, 3, 3), (R, 1, 3)
    rest = velocity - np.einsum("rfij,fj->rfi", jac_r, fixed)  # (R, F, 3)
    free_jac = jac_r * free[None, :, None, :]  # the fixed joints' columns zeroed
    rates = np.einsum("rfij,rfj->rfi", np.linalg.pinv(free_jac), rest) * free + fixed
    residual = np.linalg.norm(np.einsum("rfij,rfj->rfi", jac_r, rates) - velocity, axis=2)
    in_face = np.all(np.abs(rates) <= joint_rate_limits * (1.0 + 1e-12), axis=2)
    out[rows] = np.where(in_face, residual, np.inf).min(axis=1)
    return out


def envelope_feasible(
    targets: FloatArray,
    velocities: FloatArray | None,
    times: FloatArray,
    theta0: FloatArray,
    joint_rate_limits: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    tolerance: FloatArray,
    v_max: float | None,
) -> NDArray[np.bool_]:
    """For each time, whether the arm can be in the capture envelope then, (N,).

    In the envelope: a joint vector in the reachable box puts the end-effector inside eq. 20's
    box about X_T (`cube_reachable`, exact), and, with ``v_max``, joint rates within
    their limits can move it within ``v_max`` of Xdot_T (`least_relative_speeds` at the
    IK solutions of X_T within `near_box` of the reachable box; where there is none, the
    speed is not what rules the time out).

    Args:
        targets: X_T(t), global, m, (N, 3).
        velocities: Xdot_T(t), global, m/s, (N, 3) (used with ``v_max`` only).
        times ... tolerance: as `feasible_solutions`.
        v_max: m/s, or None: eq. 20's box alone.
    """
    box_lo, box_hi, solutions, excess = _box_solutions(
        targets, times, theta0, joint_rate_limits, lower, upper
    )
    feasible = cube_reachable(targets, np.asarray(tolerance, dtype=float), box_lo, box_hi)
    if v_max is None or velocities is None:
        return feasible
    near = excess < near_box(tolerance)  # (N, 4), False where NaN
    rows, cols = np.nonzero(near & feasible[:, None])
    slow = np.zeros_like(near)
    slow[rows, cols] = (
        least_relative_speeds(jacobian(solutions[rows, cols]), velocities[rows], joint_rate_limits)
        <= v_max
    )
    return feasible & (slow.any(axis=1) | ~near.any(axis=1))


def held_arrivals(
    arrivals: FloatArray,
    thetas: FloatArray,
    target_positions: Sequence[Callable[[FloatArray], FloatArray]],
    target_velocities: Sequence[Callable[[FloatArray], FloatArray]] | None,
    theta0: FloatArray,
    joint_rate_limits: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    tolerance: FloatArray,
    *,
    horizons: Sequence[float],
    period: float,
    travel_times: Sequence[Callable[[FloatArray], FloatArray] | None],
    hold: float,
    v_max: float | None,
) -> tuple[FloatArray, FloatArray]:
    """The earliest entry at or after each episode's arrival from which the arm can be in the
    capture envelope for ``hold`` (see the module docstring), and a joint vector at the entry.

    The envelope (`envelope_feasible`) is tested on a grid of ``HOLD_SAMPLES`` times per
    control period. A *scan* from a time s tests the grid from s over ``hold`` and ``CHUNK``
    steps more: if it holds from s itself through ``s + hold``, s is the entry. Otherwise the
    next candidate is the first grid time after a failing one from which it holds through the
    hold, or, where no hold fits in the scan, the first passing time after the last failing
    one; the onset within the grid step before that time is found by ``REFINE`` evenly spaced
    times (to ``period / (HOLD_SAMPLES REFINE)``), and a scan from there follows. A scan that
    passes nowhere after its last failure goes on from its end. No entry whose hold ends by
    the horizon: ``inf``. Each round scans or refines every unfinished episode in one
    `envelope_feasible` call, whose rows are independent, so an episode's result is the
    same in any batch.

    Args:
        arrivals: per episode, the arrival (the first feasible time), s (inf: none), (G,).
        thetas: the joint vectors there, (G, 3).
        target_positions ... tolerance, horizons, period: as `physical_limits`.
        travel_times: per episode, as `physical_limit`'s ``travel_time`` (None: t).
        hold, v_max: the envelope.

    Returns:
        ``(entry (G,), theta (G, 3))``.
    """
    step = period / HOLD_SAMPLES
    span = math.floor(hold / step + 1e-9)  # grid steps within a hold
    scan = step * np.arange(span + CHUNK + 1)  # a scan's times after its start
    entry = np.array(arrivals, dtype=float)  # a scan's start, or the result
    best = np.array(thetas, dtype=float)
    last = np.asarray(horizons, dtype=float) - hold  # the latest entry
    entry[~(entry <= last)] = np.inf
    refining = np.zeros(entry.size, bool)  # else scanning from ``entry``
    t_lo = np.zeros(entry.size)
    active = np.flatnonzero(np.isfinite(entry))
    args = (theta0, joint_rate_limits, lower, upper, tolerance, v_max)
    while active.size:
        times = [
            refine_times(t_lo[g : g + 1], entry[g : g + 1])[0] if refining[g] else entry[g] + scan
            for g in active.tolist()
        ]
        ok = _envelope_rows(active, times, target_positions, target_velocities, travel_times, args)
        done = []
        for g, row_ok, row_times in zip(active.tolist(), ok, times, strict=True):
            if refining[g]:  # the first passing time; the last, entry[g], passes
                k = int(np.argmax(row_ok))
                entry[g], refining[g] = row_times[k], False
                continue
            failed = np.flatnonzero(~row_ok)
            if failed.size == 0 or failed[0] > span:  # holds from the start
                done.append(g)
                continue
            # Holds through the hold from k: no failure in k .. k + span
            runs = np.convolve(~row_ok, np.ones(span + 1, int), mode="valid") == 0
            holds = np.flatnonzero(runs[1:] & ~row_ok[:-1][: runs.size - 1]) + 1
            passing = np.flatnonzero(row_ok[failed[-1] :]) + failed[-1]
            k = int(holds[0]) if holds.size else int(passing[0]) if passing.size else -1
            if k < 0:  # nothing passes after the last failure: scan on from the end
                entry[g] = row_times[-1]
            else:
                t_lo[g], entry[g], refining[g] = row_times[k - 1], row_times[k], True
            if not entry[g] <= last[g]:
                entry[g] = np.inf
                done.append(g)
        active = np.setdiff1d(active, done)
    held = np.flatnonzero(np.isfinite(entry))
    if held.size:
        best[held] = _nearest_at(
            held, entry[held], best[held], target_positions, travel_times, args[:4]
        )
    return entry, best


def _nearest_at(
    episodes: NDArray[np.intp],
    times: FloatArray,
    starts: FloatArray,
    target_positions: Sequence[Callable[[FloatArray], FloatArray]],
    travel_times: Sequence[Callable[[FloatArray], FloatArray] | None],
    args: tuple,
) -> FloatArray:
    """Per episode, the joint vector of the reachable box at its time whose end-effector is
    nearest X_T then (`nearest_in_box` from ``starts`` and from each IK solution), (E, 3);
    ``args``: theta0, joint_rate_limits, lower, upper."""
    t = times[:, None]
    targets = np.concatenate([target_positions[g](t[i]) for i, g in enumerate(episodes.tolist())])
    moved = np.array(
        [
            t[i, 0] if travel_times[g] is None else float(travel_times[g](t[i])[0])
            for i, g in enumerate(episodes.tolist())
        ]
    )
    box_lo, box_hi, solutions, _ = _box_solutions(targets, moved, *args)
    candidates = np.concatenate((starts[:, None], solutions), axis=1)  # (E, 5, 3)
    candidates = np.where(np.isnan(candidates), starts[:, None], candidates)
    count = candidates.shape[1]
    q = nearest_in_box(
        candidates.reshape(-1, 3),
        np.repeat(targets, count, axis=0),
        np.repeat(box_lo, count, axis=0),
        np.repeat(box_hi, count, axis=0),
    ).reshape(-1, count, 3)
    miss = np.linalg.norm(forward_kinematics(q) - targets[:, None], axis=2)
    return q[np.arange(q.shape[0]), np.argmin(miss, axis=1)]


def _envelope_rows(
    episodes: NDArray[np.intp],
    times: Sequence[FloatArray],
    target_positions: Sequence[Callable[[FloatArray], FloatArray]],
    target_velocities: Sequence[Callable[[FloatArray], FloatArray]] | None,
    travel_times: Sequence[Callable[[FloatArray], FloatArray] | None],
    args: tuple,
) -> list[NDArray[np.bool_]]:
    """`envelope_feasible` of each episode's ``times``, in one call; per episode."""
    targets, velocities, moved = [], [], []
    for g, t in zip(episodes.tolist(), times, strict=True):
        targets.append(target_positions[g](t))
        if target_velocities is not None:
            velocities.append(target_velocities[g](t))
        travel = travel_times[g]
        moved.append(t if travel is None else travel(t))
    ok = envelope_feasible(
        np.concatenate(targets),
        np.concatenate(velocities) if velocities else None,
        np.concatenate(moved),
        *args,
    )
    return np.split(ok, np.cumsum([t.size for t in times])[:-1])


def cube_reachable(
    goal: FloatArray, tolerance: FloatArray, lo: FloatArray, hi: FloatArray
) -> NDArray[np.bool_]:
    """Whether some joint vector in the box [lo, hi] puts the end-effector inside eq. 20's box
    about ``goal`` (closed; component-wise within ``tolerance``), exactly, (M,).

    Joint 1 turns the arm about the z axis; joints 2 and 3 place the end-effector in the arm's
    plane at ``(r, z)``, r its signed distance from the axis. Eq. 20's box seen in that plane
    is the rectangle Q of the z range ``z +- epsilon_z`` and the r range between the least and
    the largest distance of its horizontal square from the axis (every distance between is
    met at some azimuth); r < 0 (joint 1 facing away, turned by pi) mirrors it. Where joint 1's
    range covers every azimuth of the square (from the axis), the test is whether Q meets the
    planar reach ``P = g([lo2, hi2] x [lo3, hi3])``, g the planar kinematics; where it covers
    none, that side is out; where some, the answer is True (a lower bound stays one).

    P is bounded by four circular arcs (``distance_lower_bound``): theta3 fixed, radius
    ``||f||`` about joint 2 (the arm turns rigidly with theta2); theta2 fixed, radius l2 about
    the elbow. Where ``|theta3| < pi/2`` over the box and theta2 spans less than pi, g is one to
    one on it, and two such regions meet exactly where a corner of one lies in the other or
    an arc crosses an edge of Q (closed sets: touching counts). Elsewhere the answer is True.

    Args:
        goal: capture points X_T, global, m, (M, 3).
        tolerance: epsilon, m, (3,).
        lo, hi: the reachable joint boxes, rad, (M, 3).
    """
    x, y, z = goal[:, 0], goal[:, 1], goal[:, 2]
    ex, ey, ez = (float(e) for e in tolerance)
    rho = np.hypot(x, y)
    near = np.hypot(np.maximum(np.abs(x) - ex, 0.0), np.maximum(np.abs(y) - ey, 0.0))
    far = np.hypot(np.abs(x) + ex, np.abs(y) + ey)
    # joint 1: the square's azimuths (from the axis) lie within +-width of the goal's
    circumradius = math.hypot(ex, ey)
    with np.errstate(divide="ignore", invalid="ignore"):
        width = np.where(rho > circumradius, np.arcsin(np.minimum(circumradius / rho, 1.0)), np.pi)
    azimuth = np.arctan2(y, x)
    regular = (lo[:, 2] > -np.pi / 2) & (hi[:, 2] < np.pi / 2) & (hi[:, 1] - lo[:, 1] < np.pi)
    out = np.zeros(goal.shape[0], bool)
    for side in (1.0, -1.0):
        centre = azimuth + (0.0 if side > 0 else np.pi)
        shifted = lo[:, 0] + np.mod(centre - lo[:, 0], 2.0 * np.pi)  # in [lo1, lo1 + 2 pi)
        missed = (
            (width < np.pi)
            & (shifted - width > hi[:, 0])
            & (shifted + width - 2.0 * np.pi < lo[:, 0])
        )
        rows = np.flatnonzero(~missed & regular & ~out)
        out |= ~missed & ~regular
        if rows.size:
            r_lo, r_hi = (near[rows], far[rows]) if side > 0 else (-far[rows], -near[rows])
            out[rows] = _planar_meets(
                r_lo, r_hi, z[rows] - ez, z[rows] + ez, lo[rows, 1:], hi[rows, 1:]
            )
    return out


def _planar_meets(
    r_lo: FloatArray,
    r_hi: FloatArray,
    z_lo: FloatArray,
    z_hi: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
) -> NDArray[np.bool_]:
    """Whether the rectangle ``[r_lo, r_hi] x [z_lo, z_hi]`` meets ``g([lo2, hi2] x [lo3, hi3])``
    (``lo``, ``hi`` the (theta2, theta3) bounds, (M, 2)), g one to one there (see
    `cube_reachable`), (M,)."""
    slack = 1e-12  # m, rad: touching counts
    lo2, hi2, lo3, hi3 = lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]
    # Q's corners in P: their (theta2, theta3) with cos theta3 > 0 in the box
    r = np.stack([r_lo, r_hi, r_lo, r_hi])  # (4, M)
    zz = np.stack([z_lo, z_lo, z_hi, z_hi])
    s3 = (r * r + zz * zz - L1 * L1 - L2 * L2) / (2.0 * L1 * L2)
    with np.errstate(invalid="ignore"):
        t3 = np.arcsin(s3)  # NaN out of reach: compares False
    t2 = np.arctan2(zz, r) + np.arctan2(L2 * np.cos(t3), L1 + L2 * s3)
    t2 = lo2 + np.mod(t2 - lo2, 2.0 * np.pi)
    inside = (t2 <= hi2 + slack) & (t3 >= lo3 - slack) & (t3 <= hi3 + slack)
    meets = inside.any(axis=0)
    # P's corners in Q
    c2 = np.stack([lo2, hi2, lo2, hi2])
    c3 = np.stack([lo3, lo3, hi3, hi3])
    pr = L1 * np.cos(c2) + L2 * np.sin(c2 + c3)
    pz = L1 * np.sin(c2) - L2 * np.cos(c2 + c3)
    meets |= (
        (pr >= r_lo - slack) & (pr <= r_hi + slack) & (pz >= z_lo - slack) & (pz <= z_hi + slack)
    ).any(axis=0)
    # P's arcs (4, M) across Q's edges (4, M). theta3 fixed: radius |L1 + L2 s3 - i L2 c3|
    # about joint 2, at angle theta2 - atan2(L2 c3, L1 + L2 s3); theta2 fixed: radius L2 about
    # the elbow, at angle theta2 + theta3 - pi/2.
    a = L1 + L2 * np.sin(np.stack([lo3, hi3]))
    b = L2 * np.cos(np.stack([lo3, hi3]))
    beta = np.arctan2(b, a)
    edge2 = np.stack([lo2, hi2])
    zeros = np.zeros((2, lo2.size))
    centre_r = np.concatenate((zeros, L1 * np.cos(edge2)))[:, None]  # (4, 1, M)
    centre_z = np.concatenate((zeros, L1 * np.sin(edge2)))[:, None]
    radius = np.concatenate((np.hypot(a, b), np.full((2, lo2.size), L2)))[:, None]
    first = np.concatenate((lo2 - beta, edge2 + lo3 - np.pi / 2))[:, None]
    span = np.concatenate((np.broadcast_to(hi2 - lo2, (2, lo2.size)), np.stack([hi3 - lo3] * 2)))
    span = span[:, None]
    # Q's edges: z = level (horizontal, r between low and high) or r = level (vertical)
    level = np.stack([z_lo, z_hi, r_lo, r_hi])[None]  # (1, 4, M)
    low = np.stack([r_lo, r_lo, z_lo, z_lo])[None]
    high = np.stack([r_hi, r_hi, z_hi, z_hi])[None]
    horizontal = np.array([True, True, False, False])[None, :, None]
    centre_level = np.where(horizontal, centre_z, centre_r)  # (4, 4, M)
    centre_other = np.where(horizontal, centre_r, centre_z)
    offset = level - centre_level
    with np.errstate(invalid="ignore"):
        half = np.sqrt(radius * radius - offset * offset)  # NaN: the circle misses the line
    for along in (half, -half):
        angle = np.where(horizontal, np.arctan2(offset, along), np.arctan2(along, offset))
        other = centre_other + along
        crossing = (other >= low - slack) & (other <= high + slack)
        on_arc = np.mod(angle - first + slack, 2.0 * np.pi) <= span + 2.0 * slack
        meets |= (crossing & on_arc).any(axis=(0, 1))
    return meets
