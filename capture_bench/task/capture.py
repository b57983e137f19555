"""The capture test of eq. 20, applied over a whole control step, for M steps at once.

Eq. 20 declares a capture when ``|X_E - X_T| < epsilon`` component-wise. Testing only at the ends
of a step would let a fast pass through the tolerance box go unseen, so the test is applied to
the whole step. Within a step the joints move linearly, ``theta(s) = theta0 + s dtheta`` for
``s in [0, 1]``, so the end-effector follows the arc ``f(theta(s))``. On a straight segment, the
relative vector ``d(s) = d0 + s (d1 - d0)`` is inside the box on one open interval of s, found
exactly (`inside_intervals`). The arc sags from its chord by at most
``(l1 + l2) (sum |dtheta_i|)^2 / 8`` (every second derivative of f is bounded by l1 + l2,
`arc_sag_bounds`); where that exceeds ``ARC_RESOLUTION``, the step is cut into enough
pieces that each piece's chord is within ``ARC_RESOLUTION`` of the arc
(`inside_intervals_along_arc`). Joint 1 turns up to 0.5 rad per step, so this matters.

A hold (``capture.hold`` of a scenario, seconds): the capture requires eq. 20 to hold
*continuously* for ``hold`` s. The stays of a whole step along the arc are the chords' intervals,
joined where one chord's stay reaches its end and the next one's starts at its beginning
(`inside_intervals_along_arc`): the step's entries *and* exits, to ``ARC_RESOLUTION``.
`held_capture` walks them carrying when the stay in progress began from one step to the
next: the capture completes at entry + hold, and leaving the box before restarts the clock at the
next entry. With ``hold = 0`` it is the first entry.

The capture envelope adds a bound on speed (``capture.v_max`` of a scenario, m/s): a capture a
gripper could make needs the *instantaneous* velocity of the end-effector relative to the capture
point, ``v(s) = J(theta(s)) dtheta/dt - Xdot_T(t0 + s dt)``, to be at most ``v_max`` as well,
for the whole hold (`relative_velocities`). Within a step the joint rates are constant, but
``J`` turns with the arm, so ``v`` is tested along the step: at `speed_pieces` + 1 points,
enough that ``v`` is within ``VELOCITY_RESOLUTION`` of the straight line between two of them
(`slow_intervals_along_arc`), each piece's slow stretch solved exactly on that line
(`slow_intervals`), and intersected with the stays inside the box (`intersect`).
The speeds over a stretch of a step (`speeds_between`: the largest relative speed over a
hold) are taken on the same grid and at the stretch's ends.

Every test here takes M steps as rows, (M, 3) arrays; one step is the case M = 1. The arc walk and
the hold are per step (a Python loop over the few steps that come near the target).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sim.kinematics import L1, L2, ArmPose, arm_pose, forward_kinematics

FloatArray = NDArray[np.float64]
Intervals = list[tuple[float, float]]
ARC_RESOLUTION = 1e-5  # m: largest allowed gap between the end-effector's arc and a test chord
#: m/s: largest allowed gap between the end-effector's relative velocity along a step and the
#: straight line between two of the points it is computed at
VELOCITY_RESOLUTION = 1e-4


def inside_intervals(
    d0: FloatArray, d1: FloatArray, tolerance: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """The fractions ``(lo, hi)`` of each of M steps, ``0 <= lo < hi <= 1``, between which
    ``|d0 + s (d1 - d0)| < tolerance`` in every component; NaN where never.

    Args:
        d0: X_E - X_T at the start of each step, m, (M, 3).
        d1: X_E - X_T at the end of each step, m, (M, 3).
        tolerance: epsilon, m, (3,) (or a scalar).

    Returns:
        ``(lo, hi)``, (M,) each: the open interval of s inside the box, clipped to [0, 1]
        (``hi == 1``: still inside at the step's end, ``lo == 0``: already inside at its start),
        or NaN. Each component is inside its box on an open interval of s; the box is inside
        where all of them overlap, so touching ends (``lo == hi``) is not an entry. Each row's
        floats do not depend on the other rows.
    """
    e = np.broadcast_to(np.asarray(tolerance, dtype=float), (3,))
    slope = d1 - d0
    flat = slope == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        s_a, s_b = (-e - d0) / slope, (e - d0) / slope
    lo = np.maximum(np.where(flat, -np.inf, np.minimum(s_a, s_b)).max(axis=1), 0.0)
    hi = np.minimum(np.where(flat, np.inf, np.maximum(s_a, s_b)).min(axis=1), 1.0)
    never = (flat & (np.abs(d0) >= e)).any(axis=1) | (lo >= hi)  # open intervals: lo == hi misses
    return np.where(never, np.nan, lo), np.where(never, np.nan, hi)


def held_capture(
    intervals: Iterable[tuple[float, float]], since: float, t0: float, dt: float, hold: float
) -> tuple[float | None, float]:
    """Eq. 20 held for ``hold`` s: when the capture completes in one step, if it does.

    Args:
        intervals: the step's stays inside the tolerance box, fractions ``(lo, hi)`` of the step
            in increasing order (a row of `inside_intervals`, or
            `inside_intervals_along_arc`).
        since: when the stay in progress at the step's start began, s (NaN: outside then).
        t0, dt: the step's start and real period, s.
        hold: how long eq. 20 must hold without a break, s (0: the first entry captures).

    Returns:
        ``(capture_time, since)``: the time the hold completes (entry + hold, s; None if not in
        this step) and when the stay in progress at the step's end began (NaN: outside then; on
        a capture, the captured stay's entry). A stay that starts at the step's start continues
        ``since``; any other entry starts the clock again.
    """
    start = math.nan
    for lo, hi in intervals:
        start = since if lo == 0.0 and not math.isnan(since) else t0 + lo * dt
        done = start + hold
        if done <= t0 + hi * dt:
            return done, start
        if hi < 1.0:
            start = math.nan  # left the box inside the step
    return None, start


def arc_sag_bounds(delta_theta: FloatArray) -> FloatArray:
    """Upper bound on the distance between the end-effector's arc and its chord in each of M
    steps, m, (M,).

    Args:
        delta_theta: the joint increments of the steps, rad, (M, 3).
    """
    total = np.add.reduce(np.abs(delta_theta), axis=1)
    return (L1 + L2) * total * total / 8.0


def inside_intervals_along_arc(
    theta0: ArrayLike,
    delta_theta: ArrayLike,
    target_at: Callable[[FloatArray], FloatArray],
    tolerance: ArrayLike,
) -> list[tuple[float, float]]:
    """The fractions of one step during which eq. 20 holds along the end-effector's true arc:
    `inside_intervals_along_arcs` for M = 1.

    Args:
        theta0: joint angles at the start of the step, rad, (3,).
        delta_theta: joint increment of the step, rad, (3,).
        target_at: X_T at fractions s of the step, (K,) -> (K, 3), global, m.
        tolerance: epsilon, m, (3,) or scalar.
    """
    theta = np.asarray(theta0, dtype=float)[None]
    delta = np.asarray(delta_theta, dtype=float)[None]
    return inside_intervals_along_arcs(theta, delta, [target_at], tolerance)[0]


def inside_intervals_along_arcs(
    theta0: FloatArray,
    delta_theta: FloatArray,
    targets_at: Sequence[Callable[[FloatArray], FloatArray]],
    tolerance: ArrayLike,
) -> list[list[tuple[float, float]]]:
    """The fractions of each of M steps during which eq. 20 holds along the end-effector's true
    arc.

    Args:
        theta0: joint angles at the start of each step, rad, (M, 3).
        delta_theta: joint increment of each step, rad, (M, 3).
        targets_at: per step, X_T at fractions s of the step, (K,) -> (K, 3), global, m.
        tolerance: epsilon, m, (3,) or scalar.

    Returns:
        Per step, open intervals ``(lo, hi)`` of s in [0, 1], in order and disjoint, exact to
        ``ARC_RESOLUTION`` along the arc: the arc is cut into chords within ``ARC_RESOLUTION`` of
        it (see the module docstring), each chord's stay is a row of `inside_intervals`,
        and a stay that reaches a chord's end joins the next chord's stay that starts there.
        Every step's chords are tested in one call, and each row's floats are those of the step
        alone (the arithmetic is element by element).
    """
    sag = arc_sag_bounds(delta_theta)
    pieces = [max(1, math.ceil(math.sqrt(float(x) / ARC_RESOLUTION))) for x in sag]
    counts = [p + 1 for p in pieces]
    # np.linspace(0, 1, p + 1) of every step at once, as numpy computes it: i * (1 / p), the
    # last point set to 1
    index = np.arange(sum(counts)) - np.repeat(np.cumsum(counts) - counts, counts)
    s = index * np.repeat(1.0 / np.array(pieces, dtype=float), counts)
    ends = np.cumsum(counts) - 1
    s[ends] = 1.0
    fractions = np.split(s, ends[:-1] + 1)
    theta = np.repeat(theta0, counts, axis=0) + s[:, None] * np.repeat(delta_theta, counts, axis=0)
    targets = np.concatenate([at(f) for at, f in zip(targets_at, fractions, strict=True)])
    relative = forward_kinematics(theta) - targets
    # Every chord at once (the pairs across two steps' points are tested too, and skipped); the
    # walk below visits only the chords with a stay, which are few.
    los, his = inside_intervals(relative[:-1], relative[1:], tolerance)
    out: list[list[tuple[float, float]]] = []
    first = 0  # the step's first point's row
    for p in pieces:
        chords = slice(first, first + p)
        out.append(_joined_stays(los[chords], his[chords], p))
        first += p + 1
    return out


def _joined_stays(los: FloatArray, his: FloatArray, pieces: int) -> list[tuple[float, float]]:
    """The stays of one step from its chords' ``(lo, hi)`` (NaN: none), as fractions of the
    step, a stay reaching a chord's end joined to the next chord's stay from its start."""
    intervals: list[tuple[float, float]] = []
    joins = False  # the last chord with a stay reached its end (so the next chord starts inside)
    for k in np.flatnonzero(~np.isnan(los)).tolist():
        lo, hi = float(los[k]), float(his[k])
        if joins and lo == 0.0:
            intervals[-1] = (intervals[-1][0], (k + hi) / pieces)
        else:
            intervals.append(((k + lo) / pieces, (k + hi) / pieces))
        joins = hi == 1.0
    if intervals and joins:
        intervals[-1] = (intervals[-1][0], 1.0)  # (pieces - 1 + 1) / pieces may round below 1
    return intervals


def first_entry_along_arc(
    theta0: ArrayLike,
    delta_theta: ArrayLike,
    target_at: Callable[[FloatArray], FloatArray],
    tolerance: ArrayLike,
) -> float | None:
    """Earliest fraction s of the step at which eq. 20 holds along the end-effector's true arc:
    the start of the first of `inside_intervals_along_arc` (arguments as there).

    Returns:
        s in [0, 1] or None, exact to ``ARC_RESOLUTION`` along the arc.
    """
    intervals = inside_intervals_along_arc(theta0, delta_theta, target_at, tolerance)
    return intervals[0][0] if intervals else None


def closest_approaches(d0: FloatArray, d1: FloatArray) -> FloatArray:
    """Smallest ``|d0 + s (d1 - d0)|`` over ``s in [0, 1]`` (Euclidean) of M segments,
    (M, 3), (M, 3) -> (M,), m."""
    slope = d1 - d0
    denom = np.einsum("ij,ij->i", slope, slope)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip(-np.einsum("ij,ij->i", d0, slope) / denom, 0.0, 1.0)
    s[denom == 0.0] = 0.0
    return np.linalg.norm(d0 + s[:, None] * slope, axis=1)


def approach_lower_bounds(d0: FloatArray, d1: FloatArray) -> FloatArray:
    """A lower bound on `closest_approaches`, m, (M,), in five numpy calls: along a
    segment each component stays between its ends, so ``|d(s)|`` is at least the largest
    component's distance from 0 over its range (negative where every range straddles 0; NaN
    where an end is NaN). A screen: a step whose bound exceeds the tolerance's radius (plus the
    arc's sag) cannot capture."""
    return np.maximum.reduce(np.maximum(np.minimum(d0, d1), -np.maximum(d0, d1)), axis=1)


def row_norms(v: FloatArray) -> FloatArray:
    """Euclidean norms of the 3-vectors of M rows: (M, 3) -> (M,), or K vectors side by side,
    (M, 3K) -> (M, K). ``np.linalg.norm(v, axis=-1)``'s arithmetic (the same floats) in a few
    numpy calls instead of its dozen."""
    squared = v * v
    if v.shape[1] > 3:
        squared = squared.reshape(v.shape[0], v.shape[1] // 3, 3)
    return np.sqrt(np.add.reduce(squared, axis=-1))


def relative_velocities(
    pose: ArmPose, joint_rates: FloatArray, target_velocity: FloatArray
) -> FloatArray:
    """The end-effector's instantaneous velocity relative to the capture point,
    ``J(theta) theta_dot - Xdot_T``, m/s, (K, 3), with eq. 9's Jacobian's entries multiplied out
    from the pose's sines and cosines. Element by element: a row's floats do not depend on the
    others.

    Args:
        pose: the arm at K joint vectors theta, `capture_bench.sim.kinematics.arm_pose`.
        joint_rates: joint rates theta_dot, rad/s, (K, 3) (a step's ``delta_theta / dt`` on
            each row).
        target_velocity: Xdot_T at the same instants, global, m/s, (K, 3).
    """
    w1, w2, w3 = joint_rates[:, 0], joint_rates[:, 1], joint_rates[:, 2]
    c1, s1, r = pose.cos1, pose.sin1, pose.r
    forearm = L2 * pose.cos23
    radial = (forearm - L1 * pose.sin2) * w2 + forearm * w3  # dr/dt
    around = r * w1
    out = np.empty(joint_rates.shape)
    out[:, 0] = radial * c1 - around * s1
    out[:, 1] = radial * s1 + around * c1
    out[:, 2] = r * w2 + L2 * pose.sin23 * w3
    out -= target_velocity
    return out


def slow_intervals(v0: FloatArray, v1: FloatArray, v_max: float) -> tuple[FloatArray, FloatArray]:
    """The fractions ``(lo, hi)`` of each of M pieces, ``0 <= lo <= hi <= 1``, on which
    ``|v0 + u (v1 - v0)| <= v_max``; NaN where never.

    ``|v(u)|^2`` is a convex quadratic in u, so the set is one closed interval, solved in
    closed form.

    Args:
        v0, v1: relative velocity at the start and the end of each piece, m/s, (M, 3).
        v_max: the bound, m/s.
    """
    dv = v1 - v0
    a = np.einsum("ij,ij->i", dv, dv)
    b = 2.0 * np.einsum("ij,ij->i", v0, dv)
    c = np.einsum("ij,ij->i", v0, v0) - v_max * v_max
    disc = b * b - 4.0 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.sqrt(np.maximum(disc, 0.0))
        u1, u2 = (-b - root) / (2.0 * a), (-b + root) / (2.0 * a)
    flat = a == 0.0  # constant velocity over the piece
    u1 = np.where(flat, np.where(c <= 0.0, 0.0, np.nan), u1)
    u2 = np.where(flat, np.where(c <= 0.0, 1.0, np.nan), u2)
    lo, hi = np.maximum(u1, 0.0), np.minimum(u2, 1.0)
    never = (~flat & (disc < 0.0)) | ~(lo <= hi)  # NaN compares false: never
    return np.where(never, np.nan, lo), np.where(never, np.nan, hi)


def speed_pieces(delta_theta: ArrayLike, dt: float) -> int:
    """How many pieces a step is cut into for the speed test: the end-effector's velocity
    ``J(theta(s)) dtheta/dt`` has a second derivative in s of at most ``(l1 + l2) S^3 / dt``
    (``S = sum |dtheta_i|``; every third derivative of f is bounded by l1 + l2), so on pieces of
    ``1/K`` it is within ``(l1 + l2) S^3 / (8 dt K^2)`` of its chord, at most
    ``VELOCITY_RESOLUTION``."""
    total = float(np.abs(np.asarray(delta_theta, dtype=float)).sum())
    curvature = (L1 + L2) * total**3 / dt
    return max(1, math.ceil(math.sqrt(curvature / (8.0 * VELOCITY_RESOLUTION))))


def slow_intervals_along_arc(
    theta0: ArrayLike,
    delta_theta: ArrayLike,
    dt: float,
    target_velocity_at: Callable[[FloatArray], FloatArray],
    v_max: float,
) -> Intervals:
    """The fractions of one step during which the end-effector's instantaneous velocity
    relative to the capture point is at most ``v_max``.

    Args:
        theta0: joint angles at the start of the step, rad, (3,).
        delta_theta: the step's joint increment, rad, (3,) (constant rates ``delta_theta / dt``).
        dt: the step's real period, s.
        target_velocity_at: Xdot_T at fractions s of the step, (K,) -> (K, 3), global, m/s.
        v_max: the bound, m/s.

    Returns:
        Closed intervals ``(lo, hi)`` of s in [0, 1], in order and disjoint, exact to
        ``VELOCITY_RESOLUTION`` (the target's velocity is taken straight between the same
        points: its acceleration, centimetres per second squared, bends it far less).
    """
    delta = np.asarray(delta_theta, dtype=float)
    pieces = speed_pieces(delta, dt)
    s = np.linspace(0.0, 1.0, pieces + 1)
    theta = np.asarray(theta0, dtype=float)[None] + s[:, None] * delta[None]
    rates = np.broadcast_to(delta / dt, theta.shape)
    v = relative_velocities(arm_pose(theta), rates, target_velocity_at(s))
    los, his = slow_intervals(v[:-1], v[1:], v_max)
    out: Intervals = []
    joins = -1  # the piece a slow stretch reaching its last piece's end goes on into
    for k in np.flatnonzero(~np.isnan(los)).tolist():
        width = s[k + 1] - s[k]
        lo = float(s[k]) if los[k] == 0.0 else float(s[k] + los[k] * width)
        hi = float(s[k + 1]) if his[k] == 1.0 else float(s[k] + his[k] * width)
        if k == joins and los[k] == 0.0:
            out[-1] = (out[-1][0], hi)  # the slow stretch goes on across the pieces' joint
        else:
            out.append((lo, hi))
        joins = k + 1 if his[k] == 1.0 else -1
    return out


def speeds_between(
    theta0: ArrayLike,
    delta_theta: ArrayLike,
    dt: float,
    target_velocity_at: Callable[[FloatArray], FloatArray],
    lo: float,
    hi: float,
) -> FloatArray:
    """The end-effector's instantaneous speed relative to the capture point, ``|v(s)|`` (m/s),
    over the stretch ``[lo, hi]`` of one step: at ``lo``, at the points of
    `slow_intervals_along_arc`'s grid strictly between, and at ``hi``, in that order (so
    the first entry is ``|v(lo)|`` and the last ``|v(hi)|``; ``lo == hi`` gives that one value
    twice).

    Between two neighbouring points ``v`` is within ``VELOCITY_RESOLUTION`` of the straight line
    between its values there, whose norm is largest at one of its ends, so the largest of these
    speeds is within ``2 VELOCITY_RESOLUTION`` of the largest over the stretch.

    Args:
        theta0: joint angles at the start of the step, rad, (3,).
        delta_theta: the step's joint increment, rad, (3,) (constant rates ``delta_theta / dt``).
        dt: the step's real period, s.
        target_velocity_at: Xdot_T at fractions s of the step, (K,) -> (K, 3), global, m/s.
        lo, hi: the stretch, fractions of the step, ``0 <= lo <= hi <= 1``.
    """
    delta = np.asarray(delta_theta, dtype=float)
    grid = np.linspace(0.0, 1.0, speed_pieces(delta, dt) + 1)
    s = np.concatenate(([lo], grid[(grid > lo) & (grid < hi)], [hi]))
    theta = np.asarray(theta0, dtype=float)[None] + s[:, None] * delta[None]
    rates = np.broadcast_to(delta / dt, theta.shape)
    return row_norms(relative_velocities(arm_pose(theta), rates, target_velocity_at(s)))


def intersect(
    first: Sequence[tuple[float, float]], second: Sequence[tuple[float, float]]
) -> Intervals:
    """The fractions of a step in both lists of intervals (each in order and disjoint), in
    order; a stretch where they only touch (``lo == hi``) is left out."""
    out: Intervals = []
    i = j = 0
    while i < len(first) and j < len(second):
        lo, hi = max(first[i][0], second[j][0]), min(first[i][1], second[j][1])
        if lo < hi:
            out.append((lo, hi))
        if first[i][1] < second[j][1]:
            i += 1
        else:
            j += 1
    return out
