"""Eq. 20 over a whole step, against hand cases and a dense brute force."""

import numpy as np

from capture_bench.sim.kinematics import forward_kinematics
from capture_bench.task.capture import (
    arc_sag_bound,
    closest_approach,
    first_entry_along_arc,
    first_entry_fraction,
    within_tolerance,
)

EPS = np.full(3, 1e-3)


def test_pass_through_the_box_mid_step_is_a_capture():
    # Relative vector goes from (-5, 0, 0) mm to (+5, 0, 0) mm: enters the 1 mm box at s = 0.4.
    s = first_entry_fraction([-5e-3, 0, 0], [5e-3, 0, 0], EPS)
    assert s is not None and abs(s - 0.4) < 1e-12


def test_a_miss_by_more_than_epsilon_in_one_component_is_not():
    assert first_entry_fraction([-5e-3, 2e-3, 0], [5e-3, 2e-3, 0], EPS) is None


def test_touching_the_boundary_is_not_a_capture():
    assert first_entry_fraction([1e-3, 0, 0], [3e-3, 0, 0], EPS) is None
    assert not within_tolerance([1e-3, 0, 0], EPS)


def test_agrees_with_dense_sampling():
    rng = np.random.default_rng(0)
    s_grid = np.linspace(0, 1, 20001)
    for _ in range(300):
        d0, d1 = rng.uniform(-4e-3, 4e-3, (2, 3))
        path = d0 + s_grid[:, None] * (d1 - d0)
        inside = np.all(np.abs(path) < EPS, axis=1)
        s = first_entry_fraction(d0, d1, EPS)
        if inside.any():
            assert s is not None and abs(s - s_grid[np.argmax(inside)]) < 1e-4
        else:
            assert s is None or np.all(np.abs(d0 + s * (d1 - d0)) <= EPS + 1e-12)


def test_the_arc_test_sees_a_capture_the_chord_misses_and_vice_versa():
    """Joint 1 swings 0.5 rad: the arc bulges ~1.8 cm from its chord; a target on the arc's
    midpoint is captured, one on the chord's midpoint is not."""
    theta0 = np.array([-0.25, 1.2, 0.1])
    delta = np.array([0.5, 0.0, 0.0])
    on_arc = forward_kinematics(theta0 + 0.5 * delta)
    on_chord = 0.5 * (forward_kinematics(theta0) + forward_kinematics(theta0 + delta))
    assert np.linalg.norm(on_arc - on_chord) > 0.015
    assert arc_sag_bound(delta) >= np.linalg.norm(on_arc - on_chord)
    s = first_entry_along_arc(theta0, delta, lambda s: np.tile(on_arc, (len(s), 1)), EPS)
    assert s is not None and abs(s - 0.5) < 0.01
    assert (
        first_entry_along_arc(theta0, delta, lambda s: np.tile(on_chord, (len(s), 1)), EPS) is None
    )
    # The chord test alone gets both wrong.
    d0, d1 = forward_kinematics(theta0) - on_chord, forward_kinematics(theta0 + delta) - on_chord
    assert first_entry_fraction(d0, d1, EPS) is not None


def test_closest_approach_against_sampling():
    rng = np.random.default_rng(1)
    s = np.linspace(0, 1, 100001)
    for _ in range(50):
        d0, d1 = rng.normal(size=(2, 3))
        dense = np.linalg.norm(d0 + s[:, None] * (d1 - d0), axis=1).min()
        assert abs(closest_approach(d0, d1) - dense) < 1e-6
