"""True target motion: velocity against finite differences, rigidity, seeded draws."""

import numpy as np
import pytest

from capture_bench.sim.target_motion import FEATURE_POINTS, sample_trajectory
from capture_bench.task.scenarios import list_scenarios, load_scenario

ANCHOR = np.array([0.4445, 0.0, 0.454025])


@pytest.mark.parametrize("name", ["paper", "circular", "tumbling", "evasive"])
def test_velocity_is_the_derivative_of_position(name):
    traj = sample_trajectory(load_scenario(name).target, np.random.default_rng(5), ANCHOR, 10.0)
    h = 1e-6
    for t in np.linspace(0.1, 9.9, 40):
        fd = (traj.position(t + h) - traj.position(t - h)) / (2 * h)
        np.testing.assert_allclose(traj.velocity(t), fd, atol=1e-7)
    times = np.linspace(0, 10, 11)
    np.testing.assert_allclose(traj.position(times), [traj.position(t) for t in times], atol=1e-15)


def test_tumbling_capture_point_velocity_is_v_plus_omega_cross_r():
    traj = sample_trajectory(
        load_scenario("tumbling").target, np.random.default_rng(1), ANCHOR, 10.0
    )
    assert traj.spin_rate > 0 and np.linalg.norm(traj.capture_offset) > 0
    t = 3.0
    r = traj.rotation(t) @ traj.capture_offset
    expected = traj.translation.velocity_at(t) + np.cross(traj.angular_velocity, r)
    np.testing.assert_allclose(traj.velocity(t), expected, atol=1e-15)


def test_feature_points_move_rigidly_and_the_first_is_the_capture_point():
    traj = sample_trajectory(
        load_scenario("tumbling").target, np.random.default_rng(2), ANCHOR, 10.0
    )
    pts = FEATURE_POINTS["non_coplanar"]
    d0 = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    for t in (0.0, 2.5, 7.0):
        g = traj.feature_points(t, pts)
        np.testing.assert_allclose(np.linalg.norm(g[:, None] - g[None], axis=2), d0, atol=1e-12)
        np.testing.assert_allclose(g[0], traj.position(t), atol=1e-15)


@pytest.mark.parametrize("name", list_scenarios())
def test_same_seed_same_trajectory_and_initial_offset_in_range(name):
    cfg = load_scenario(name).target
    a = sample_trajectory(cfg, np.random.default_rng(9), ANCHOR, 10.0)
    b = sample_trajectory(cfg, np.random.default_rng(9), ANCHOR, 10.0)
    np.testing.assert_array_equal(a.position(np.arange(5.0)), b.position(np.arange(5.0)))
    lo, hi = cfg.initial_offset
    assert lo - 1e-12 <= np.linalg.norm(a.position(0.0) - ANCHOR) <= hi + 1e-12


@pytest.mark.parametrize("name", list_scenarios())
def test_states_agree_with_the_vectorised_methods_and_place_the_points(name):
    """Every step time at once (recordings and the live single env read these rows): the true
    state as `position`, `velocity` and `rotation` give it, to rounding, and the feature points
    as the camera is given them, bit for bit from the rows; a time's rows do not depend on the
    other times asked for."""
    traj = sample_trajectory(load_scenario(name).target, np.random.default_rng(5), ANCHOR, 10.0)
    times = np.concatenate([np.arange(0.0, 9.9, 0.05), [0.123456789, 7.0000001, 9.99]])
    points = FEATURE_POINTS["non_coplanar"]
    position, velocity, rotation, seen = traj.states(times, points)
    assert traj.states(times)[3] is None
    np.testing.assert_allclose(position, traj.position(times), atol=1e-14)
    np.testing.assert_allclose(velocity, traj.velocity(times), atol=1e-14)
    np.testing.assert_allclose(rotation, traj.rotations(times), atol=1e-14)
    for k, t in enumerate(times.tolist()):
        p, r = position[k], rotation[k]
        np.testing.assert_array_equal(seen[k], p + points @ r.T)
        alone = traj.states(np.array([t]))
        for whole, one in zip((position, velocity, rotation), alone[:3], strict=True):
            np.testing.assert_array_equal(whole[k], one[0])
