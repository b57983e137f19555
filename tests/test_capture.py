"""Eq. 20 over a whole step, against hand cases and a dense brute force; the hold. Every test
takes M steps as rows; one step is M = 1 (`_interval`)."""

import math

import numpy as np
import pytest

from capture_bench.sim.kinematics import forward_kinematics
from capture_bench.task.capture import (
    approach_lower_bounds,
    arc_sag_bounds,
    closest_approaches,
    first_entry_along_arc,
    held_capture,
    inside_intervals,
    inside_intervals_along_arc,
    inside_intervals_along_arcs,
    row_norms,
)

EPS = np.full(3, 1e-3)


def _interval(d0, d1, tolerance=EPS) -> tuple[float, float] | None:
    """One step's stay inside the box, from `inside_intervals` at M = 1 (None: none)."""
    lo, hi = inside_intervals(np.array([d0], float), np.array([d1], float), tolerance)
    return None if np.isnan(lo[0]) else (float(lo[0]), float(hi[0]))


def test_pass_through_the_box_mid_step_is_a_capture():
    # Relative vector goes from (-5, 0, 0) mm to (+5, 0, 0) mm: inside the 1 mm box for
    # s in (0.4, 0.6).
    lo, hi = _interval([-5e-3, 0, 0], [5e-3, 0, 0])
    assert lo == pytest.approx(0.4, abs=1e-12) and hi == pytest.approx(0.6, abs=1e-12)


def test_a_miss_by_more_than_epsilon_in_one_component_is_not():
    assert _interval([-5e-3, 2e-3, 0], [5e-3, 2e-3, 0]) is None


def test_touching_the_boundary_is_not_a_capture():
    assert _interval([1e-3, 0, 0], [3e-3, 0, 0]) is None
    assert _interval([1e-3, 0, 0], [1e-3, 0, 0]) is None  # standing on the boundary
    assert _interval([0.5e-3, 0, 0], [0.5e-3, 0, 0]) == (0.0, 1.0)  # standing inside


def test_agrees_with_dense_sampling():
    rng = np.random.default_rng(0)
    s_grid = np.linspace(0, 1, 20001)
    d0, d1 = rng.uniform(-4e-3, 4e-3, (2, 300, 3))
    lo, _ = inside_intervals(d0, d1, EPS)
    for a, b, s in zip(d0, d1, lo, strict=True):
        inside = np.all(np.abs(a + s_grid[:, None] * (b - a)) < EPS, axis=1)
        if inside.any():
            assert abs(s - s_grid[np.argmax(inside)]) < 1e-4
        else:
            assert np.isnan(s) or np.all(np.abs(a + s * (b - a)) <= EPS + 1e-12)
    assert 50 < np.isnan(lo).sum() < 250  # both kinds tested


def test_the_arc_test_sees_a_capture_the_chord_misses_and_vice_versa():
    """Joint 1 swings 0.5 rad: the arc bulges ~1.8 cm from its chord; a target on the arc's
    midpoint is captured, one on the chord's midpoint is not."""
    theta0 = np.array([-0.25, 1.2, 0.1])
    delta = np.array([0.5, 0.0, 0.0])
    on_arc = forward_kinematics(theta0 + 0.5 * delta)
    on_chord = 0.5 * (forward_kinematics(theta0) + forward_kinematics(theta0 + delta))
    assert np.linalg.norm(on_arc - on_chord) > 0.015
    assert arc_sag_bounds(delta[None])[0] >= np.linalg.norm(on_arc - on_chord)
    s = first_entry_along_arc(theta0, delta, lambda s: np.tile(on_arc, (len(s), 1)), EPS)
    assert s is not None and abs(s - 0.5) < 0.01
    assert (
        first_entry_along_arc(theta0, delta, lambda s: np.tile(on_chord, (len(s), 1)), EPS) is None
    )
    # The chord test alone gets both wrong.
    d0, d1 = forward_kinematics(theta0) - on_chord, forward_kinematics(theta0 + delta) - on_chord
    assert _interval(d0, d1) is not None


def test_closest_approach_and_its_screen_against_sampling():
    rng = np.random.default_rng(1)
    s = np.linspace(0, 1, 100001)
    d0, d1 = rng.normal(size=(2, 50, 3))
    d1[:5] = d0[:5]  # segments of no length
    closest = closest_approaches(d0, d1)
    for a, b, got in zip(d0, d1, closest, strict=True):
        dense = np.linalg.norm(a + s[:, None] * (b - a), axis=1).min()
        assert abs(got - dense) < 1e-6
    bound = approach_lower_bounds(d0, d1)
    assert (bound <= closest).all() and (bound > 0.3 * closest).mean() > 0.5  # a useful screen
    assert np.isnan(approach_lower_bounds(np.full((1, 3), np.nan), d1[:1]))[0]  # no estimate


def test_row_norms_are_numpys_norms_float_for_float():
    v = np.random.default_rng(2).normal(size=(1000, 9)) * np.array([1e-3, 1.0, 1e3] * 3)
    np.testing.assert_array_equal(row_norms(v[:, :3]), np.linalg.norm(v[:, :3], axis=1))
    np.testing.assert_array_equal(row_norms(v), np.linalg.norm(v.reshape(-1, 3, 3), axis=2))


# --- a hold: eq. 20 without a break for `hold` s (issue 13) ------------------------------------

DT = 0.05


def _held(relative: list[list[float]], hold: float, tolerance=EPS) -> float | None:
    """Walk steps of a hand-built relative vector (its values at the step ends, m) through
    held_capture as the step rule does; the capture time or None."""
    since = math.nan
    for k in range(1, len(relative)):
        t0 = (k - 1) * DT
        interval = _interval(relative[k - 1], relative[k], tolerance)
        if interval is None:
            since = math.nan
            continue
        done, since = held_capture([interval], since, t0, DT, hold)
        if done is not None:
            return done
    return None


def _mm(*xs: float) -> list[list[float]]:
    return [[x * 1e-3, 0.0, 0.0] for x in xs]


def test_entering_and_leaving_before_the_hold_completes_is_not_a_capture():
    # Through the 1 mm box in step 0 (inside for s in (0.4, 0.6): 0.02-0.03 s) and back in step 1.
    fly_through = _mm(-5, 5, -5)
    assert _held(fly_through, hold=0.0) == pytest.approx(0.02)  # eq. 20 alone: it captures
    assert _held(fly_through, hold=0.02) is None  # two stays of 0.01 s each
    # In from s = 0.8 of step 0 (0.04 s) to s = 0.2 of step 2 (0.11 s): a stay of 0.07 s.
    visit = _mm(-5, 0, 0, -5, -5)
    assert _held(visit, hold=0.0) == pytest.approx(0.04)
    assert _held(visit, hold=0.08) is None
    assert _held(visit, hold=0.06) == pytest.approx(0.10)


def test_staying_is_a_capture_at_entry_plus_hold_possibly_mid_step():
    path = _mm(-5, 0, 0, 0, 0, 0, 0)  # entry at s = 0.8 of step 0: t = 0.04 s, then stays
    for hold in (0.0, 0.01, 0.05, 0.1, 0.137, 0.25):
        assert _held(path, hold) == pytest.approx(0.04 + hold, abs=1e-12), hold
    assert _held(path, hold=0.27) is None  # the trajectory ends at 0.3 s


def test_reentry_restarts_the_clock():
    # In from 0.04 s, out at 0.11 s (step 2), in again at 0.19 s (step 3) and stays to 0.35 s.
    path = _mm(-5, 0, 0, 5, 0, 0, 0, 0)
    assert _held(path, hold=0.05) == pytest.approx(0.09)  # the first stay lasts long enough
    assert _held(path, hold=0.1) == pytest.approx(0.19 + 0.1)  # it does not: the second counts
    assert _held(path, hold=0.0) == pytest.approx(0.04)


def test_held_capture_of_a_stay_that_began_steps_ago_and_the_stay_at_the_end():
    # Already inside since t = 0.01 s at this step's start (t0 = 0.1 s).
    assert held_capture([(0.0, 1.0)], 0.01, 0.1, DT, 0.12) == (pytest.approx(0.13), 0.01)
    done, since = held_capture([(0.0, 1.0)], 0.01, 0.1, DT, 0.2)
    assert done is None and since == 0.01  # still inside: the stay goes on
    done, since = held_capture([(0.0, 0.5)], 0.01, 0.1, DT, 0.2)
    assert done is None and math.isnan(since)  # left at s = 0.5
    # Left, then entered again in the same step: the clock restarts at the second entry.
    done, since = held_capture([(0.0, 0.2), (0.6, 1.0)], 0.01, 0.1, DT, 0.2)
    assert done is None and since == pytest.approx(0.13)
    assert held_capture([], 0.01, 0.1, DT, 0.2)[0] is None


def test_inside_interval_agrees_with_dense_sampling():
    rng = np.random.default_rng(2)
    s_grid = np.linspace(0, 1, 20001)
    for _ in range(300):
        d0, d1 = rng.uniform(-4e-3, 4e-3, (2, 3))
        inside = np.all(np.abs(d0 + s_grid[:, None] * (d1 - d0)) < EPS, axis=1)
        interval = _interval(d0, d1)
        if inside.any():
            assert interval is not None
            assert abs(interval[0] - s_grid[inside][0]) < 1e-4
            assert abs(interval[1] - s_grid[inside][-1]) < 1e-4
        elif interval is not None:
            assert interval[1] - interval[0] < 1e-4
    batched = inside_intervals(
        rng.uniform(-4e-3, 4e-3, (50, 3)), rng.uniform(-4e-3, 4e-3, (50, 3)), EPS
    )
    assert batched[0].shape == batched[1].shape == (50,)


def test_leaving_along_the_arc_mid_step_is_seen_where_the_chord_stays_inside():
    """Joint 1 swings 0.5 rad while the target follows the chord: the chord test stays inside the
    box, the arc sags ~1.8 cm away mid-step and comes back: two stays, an exit and an entry."""
    theta0 = np.array([-0.25, 1.2, 0.1])
    delta = np.array([0.5, 0.0, 0.0])
    a, b = forward_kinematics(theta0), forward_kinematics(theta0 + delta)

    def on_chord(s):
        return a + np.asarray(s)[:, None] * (b - a)

    stays = inside_intervals_along_arc(theta0, delta, on_chord, EPS)
    assert len(stays) == 2 and stays[0][0] == 0.0 and stays[1][1] == 1.0
    assert 0.0 < stays[0][1] < 0.5 < stays[1][0] < 1.0
    # Dense check of the exit and the entry along the arc.
    s = np.linspace(0, 1, 200001)
    inside = np.all(np.abs(forward_kinematics(theta0 + s[:, None] * delta) - on_chord(s)) < EPS, 1)
    assert abs(stays[0][1] - s[np.argmin(inside)]) < 1e-4
    assert abs(stays[1][0] - s[len(s) - np.argmin(inside[::-1])]) < 1e-4
    # A stay that began before the step is broken at the exit; the clock restarts at the entry.
    done, since = held_capture(stays, 0.98, 1.0, DT, 0.5)
    assert done is None and since == pytest.approx(1.0 + stays[1][0] * DT)
    assert first_entry_along_arc(theta0, delta, on_chord, EPS) == 0.0


def _chord_by_chord(theta0, delta, target_at, tolerance):
    """inside_intervals_along_arc chord by chord: each chord's stay alone (M = 1), the stays
    joined where one reaches its chord's end and the next starts at its beginning."""
    import capture_bench.task.capture as capture

    sag = arc_sag_bounds(delta[None])[0]
    pieces = max(1, math.ceil(math.sqrt(sag / capture.ARC_RESOLUTION)))
    s = np.linspace(0.0, 1.0, pieces + 1)
    relative = forward_kinematics(theta0 + s[:, None] * delta) - target_at(s)
    intervals, joins = [], False
    for k in range(pieces):
        interval = _interval(relative[k], relative[k + 1], tolerance)
        if interval is None:
            joins = False
            continue
        lo, hi = interval
        if joins and lo == 0.0:
            intervals[-1] = (intervals[-1][0], (k + hi) / pieces)
        else:
            intervals.append(((k + lo) / pieces, (k + hi) / pieces))
        joins = hi == 1.0
    if intervals and joins:
        intervals[-1] = (intervals[-1][0], 1.0)
    return intervals


def test_the_arc_walk_equals_the_chord_by_chord_walk_exactly():
    """The arc's chords are tested all at once: the stays are the chord-by-chord walk's, float
    for float, on swings whose arcs enter, leave, re-enter and stay (targets on the chord, near
    the arc, or wobbling across the box)."""
    rng = np.random.default_rng(20)
    checked = 0
    for _ in range(400):
        theta0 = rng.uniform([-1.0, 0.6, -0.5], [1.0, 1.6, 0.5])
        delta = rng.uniform(-0.5, 0.5, 3) * rng.choice([0.01, 0.1, 1.0])
        a, b = forward_kinematics(theta0), forward_kinematics(theta0 + delta)
        wobble = rng.uniform(-2e-3, 2e-3, 3)
        frequency = rng.uniform(1.0, 20.0)
        tolerance = EPS * rng.choice([1.0, 5.0, 20.0])

        def target_at(s, a=a, b=b, wobble=wobble, frequency=frequency):
            s = np.asarray(s)[:, None]
            return a + s * (b - a) + wobble * np.sin(frequency * s)

        expected = _chord_by_chord(theta0, delta, target_at, tolerance)
        assert inside_intervals_along_arc(theta0, delta, target_at, tolerance) == expected
        checked += bool(expected)
    assert checked > 50  # many swings have stays, some several


def test_arcs_walked_together_equal_each_walked_alone():
    """M steps in one call (as the step rule tests every step near its target): each step's
    stays are the chord-by-chord walk of that step alone, float for float, whatever its
    neighbours (short and long swings, entering, leaving or missing)."""
    rng = np.random.default_rng(21)
    theta0 = rng.uniform([-1.0, 0.6, -0.5], [1.0, 1.6, 0.5], (60, 3))
    delta = rng.uniform(-0.5, 0.5, (60, 3)) * rng.choice([0.01, 0.1, 1.0], (60, 1))
    a, b = forward_kinematics(theta0), forward_kinematics(theta0 + delta)
    wobble = rng.uniform(-2e-3, 2e-3, (60, 3)) * rng.choice([0.0, 1.0, 5.0], (60, 1))
    miss = rng.uniform(-0.02, 0.02, (60, 3)) * rng.choice([0.0, 1.0], (60, 1))
    a, b = a + miss, b + miss  # some pass by

    def target(i):
        return lambda s: (
            a[i] + np.asarray(s)[:, None] * (b[i] - a[i]) + wobble[i] * np.sin(9 * s)[:, None]
        )

    tolerance = EPS * 5
    targets = [target(i) for i in range(60)]
    together = inside_intervals_along_arcs(theta0, delta, targets, tolerance)
    alone = [_chord_by_chord(theta0[i], delta[i], targets[i], tolerance) for i in range(60)]
    assert together == alone
    assert 10 < sum(map(bool, alone)) < 60
    order = rng.permutation(60)  # and in another order, with other neighbours
    shuffled = inside_intervals_along_arcs(
        theta0[order], delta[order], [targets[i] for i in order], tolerance
    )
    assert shuffled == [alone[i] for i in order]
