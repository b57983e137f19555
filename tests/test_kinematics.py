"""Kinematics against independent references: finite differences, round trips, brute force."""

import numpy as np
import pytest

from capture_bench.sim import kinematics as k


def test_home_pose_is_the_documented_point():
    np.testing.assert_allclose(k.forward_kinematics(k.HOME), [0.4445, 0.0, 0.454025], atol=1e-12)


def test_jacobian_matches_central_differences():
    rng = np.random.default_rng(0)
    h = 1e-6
    for q in rng.uniform(k.JOINT_LOWER, k.JOINT_UPPER, (50, 3)):
        fd = np.column_stack(
            [
                (k.forward_kinematics(q + h * e) - k.forward_kinematics(q - h * e)) / (2 * h)
                for e in np.eye(3)
            ]
        )
        np.testing.assert_allclose(k.jacobian(q), fd, atol=1e-8)
        assert k.jacobian_determinant(q) == pytest.approx(np.linalg.det(k.jacobian(q)), abs=1e-12)


def test_ik_round_trip_over_random_reachable_points():
    rng = np.random.default_rng(1)
    for q in rng.uniform(k.JOINT_LOWER, k.JOINT_UPPER, (500, 3)):
        x = k.forward_kinematics(q)
        solutions = k.inverse_kinematics(x)
        np.testing.assert_allclose(
            k.forward_kinematics(solutions), np.tile(x, (len(solutions), 1)), atol=1e-9
        )
        assert np.any(np.all(np.abs(solutions - q) < 1e-9, axis=1)), "the generating pose is found"


def test_ik_finds_all_four_solutions_and_none_out_of_reach():
    x = k.forward_kinematics([0.3, 1.0, 0.2])
    assert len(k.inverse_kinematics(x)) == 4
    assert len(k.inverse_kinematics([2.0, 0.0, 0.0])) == 0


def test_batch_ik_agrees_with_single_point_ik():
    rng = np.random.default_rng(2)
    points = rng.uniform([-0.9, -0.9, -0.5], [0.9, 0.9, 0.9], (200, 3))
    batch = k.inverse_kinematics_batch(points)
    for p, rows in zip(points, batch):
        single = k.inverse_kinematics(p)
        found = rows[~np.isnan(rows[:, 0])]
        assert len(np.unique(np.round(found, 12), axis=0)) == len(single)


def test_fast_reachability_matches_batch_ik():
    rng = np.random.default_rng(3)
    points = rng.uniform([-1, -1, -0.5], [1, 1, 1], (2000, 3))
    reference = np.any(k.within_limits(k.inverse_kinematics_batch(points)), axis=1)
    fast = np.array([k.reachable(p) for p in points])
    np.testing.assert_array_equal(fast, reference)
    assert 0.1 < reference.mean() < 0.9


def test_joint_limits_keep_singularities_out():
    """Brute force over the joint-limit box: det J = l1 l2 r cos(theta3) stays away from zero."""
    t2 = np.linspace(k.JOINT_LOWER[1], k.JOINT_UPPER[1], 200)
    t3 = np.linspace(k.JOINT_LOWER[2], k.JOINT_UPPER[2], 200)
    g2, g3 = np.meshgrid(t2, t3)
    q = np.stack([np.zeros_like(g2), g2, g3], axis=-1).reshape(-1, 3)
    det = k.jacobian_determinant(q)
    assert np.all(det > 5e-3)
    r = np.hypot(*k.forward_kinematics(q)[:, :2].T)
    assert r.min() > 0.07
