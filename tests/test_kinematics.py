"""Kinematics against independent references: finite differences, round trips, brute force."""

import numpy as np
import pytest
from references.scalar_kinematics import inverse_kinematics as scalar_inverse_kinematics

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
        assert k.jacobian(q).shape == (3, 3)
        np.testing.assert_allclose(k.jacobian(q), fd, atol=1e-8)
        assert k.jacobian_determinant(q) == pytest.approx(np.linalg.det(k.jacobian(q)), abs=1e-12)


def test_jacobian_of_joint_vectors_on_any_axes_is_vector_by_vector():
    rng = np.random.default_rng(5)
    q = rng.uniform(k.JOINT_LOWER, k.JOINT_UPPER, (4, 6, 3))
    batch = k.jacobian(q)
    assert batch.shape == (4, 6, 3, 3)
    np.testing.assert_array_equal(k.jacobian(q[2, 5]), batch[2, 5])
    np.testing.assert_array_equal(k.jacobian(q.reshape(-1, 3)).reshape(4, 6, 3, 3), batch)


def _found(solutions):
    """The rows of ``solutions`` (4, 3) that are solutions (not NaN)."""
    return solutions[~np.isnan(solutions[:, 0])]


def test_ik_round_trip_over_random_reachable_points():
    rng = np.random.default_rng(1)
    thetas = rng.uniform(k.JOINT_LOWER, k.JOINT_UPPER, (500, 3))
    points = k.forward_kinematics(thetas)
    all_solutions = k.inverse_kinematics(points)
    assert all_solutions.shape == (500, 4, 3)
    assert not np.any(np.isnan(all_solutions))
    np.testing.assert_allclose(
        k.forward_kinematics(all_solutions),
        np.broadcast_to(points[:, None], (500, 4, 3)),
        atol=1e-9,
    )
    for q, solutions in zip(thetas, all_solutions):
        assert np.any(np.all(np.abs(solutions - q) < 1e-9, axis=1)), "the generating pose is found"


def test_ik_of_one_point_and_of_points_on_more_axes_is_row_by_row():
    rng = np.random.default_rng(4)
    points = rng.uniform([-0.9, -0.9, -0.5], [0.9, 0.9, 0.9], (2, 5, 3))
    solutions = k.inverse_kinematics(points)
    assert solutions.shape == (2, 5, 4, 3)
    one = k.inverse_kinematics(points[1, 3])
    assert one.shape == (4, 3)
    np.testing.assert_array_equal(one, solutions[1, 3])
    np.testing.assert_array_equal(k.inverse_kinematics(points.reshape(-1, 3))[8], one)


def test_ik_finds_all_four_solutions_and_none_out_of_reach():
    x = k.forward_kinematics([0.3, 1.0, 0.2])
    assert len(_found(k.inverse_kinematics(x))) == 4
    assert np.all(np.isnan(k.inverse_kinematics([2.0, 0.0, 0.0])))


def test_ik_wraps_angles_to_minus_pi_inclusive_pi_exclusive():
    """On the +x axis joint 1 facing away is pi, given as -pi."""
    solutions = _found(k.inverse_kinematics([0.5, 0.0, 0.2]))
    np.testing.assert_array_equal(solutions[2:, 0], [-np.pi, -np.pi])
    assert np.all((solutions >= -np.pi) & (solutions < np.pi))


def _as_set(solutions, tol=1e-12):
    """Distinct rows of ``solutions`` (K, 3), an angle of -pi read as pi (the reference's wrap)."""
    rows = np.where(np.isclose(solutions, -np.pi, rtol=0.0, atol=tol), np.pi, solutions)
    distinct = []
    for row in rows:
        if not any(np.all(np.abs(row - other) <= tol) for other in distinct):
            distinct.append(row)
    return distinct


def _same_sets(first, second, tol=1e-12):
    return len(first) == len(second) and all(
        any(np.all(np.abs(a - b) <= tol) for b in second) for a in first
    )


def test_ik_agrees_with_the_scalar_reference_in_and_out_of_reach():
    """Solutions as sets, to 1e-12 rad, over points inside, near the edge of and out of reach
    (|X| up to 1.1 (l1 + l2) and inside |l1 - l2|), and on the x-z plane."""
    rng = np.random.default_rng(2)
    reach = k.L1 + k.L2
    directions = rng.normal(size=(600, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radii = np.concatenate(
        [
            rng.uniform(0.0, 1.1 * reach, 400),
            reach * (1.0 + rng.uniform(-1e-9, 1e-9, 50)),  # near the edge of the reach
            reach * (1.0 + rng.uniform(0.0, 1e-13, 50)),  # on it: the two elbows are one
            rng.uniform(0.0, abs(k.L1 - k.L2), 100),  # inside the inner edge: out of reach
        ]
    )
    points = directions * radii[:, None]
    points[::20, 1] = 0.0  # on the x-z plane, where joint 1 is 0 or pi
    all_solutions = k.inverse_kinematics(points)
    counts = []
    for point, solutions in zip(points, all_solutions):
        reference = scalar_inverse_kinematics(point)
        found = _found(solutions)
        assert len(found) in (0, 4)
        assert _same_sets(_as_set(found), _as_set(reference)), point
        counts.append(len(reference))
    assert {0, 2, 4} <= set(counts)  # out of reach, on the edge and inside are all tried


def test_reachability_with_the_published_limits_matches_every_ik_solution():
    rng = np.random.default_rng(3)
    points = rng.uniform([-1, -1, -0.5], [1, 1, 1], (2000, 3))
    reference = np.any(k.within_limits(k.inverse_kinematics(points)), axis=1)
    fast = k.reachable(points)
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
