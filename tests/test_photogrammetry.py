"""Photogrammetry (eqs. 1-2): analytic Jacobian and pose recovery."""

from __future__ import annotations

import numpy as np
import pytest

from capture_bench.sensing.photogrammetry import (
    levenberg_marquardt,
    pose_features,
    pose_projection,
    project_poses,
    projection_table,
    solve_pose,
)
from capture_bench.sim.rotations import euler_to_matrix, matrix_to_euler

F = 0.008
PITCH = 3.75e-6
NON_COPLANAR = np.array([(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.05)], dtype=float)
SQUARE = np.array([(0, 0, 0), (0.1, 0, 0), (0.1, 0.1, 0), (0, 0.1, 0)], dtype=float)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniform random rotation matrix (normalised Gaussian quaternion)."""
    w, x, y, z = rng.normal(size=4)
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def random_pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A target 0.8-1.6 m in front of the camera, any orientation: (pose (6,), R_ct)."""
    rot = random_rotation(rng)
    t = np.array([rng.uniform(-0.1, 0.1), rng.uniform(0.8, 1.6), rng.uniform(-0.1, 0.1)])
    return np.concatenate([t, matrix_to_euler(rot)]), rot


def image_of(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Eq. 2 by hand from eq. 1, independent of pose_projection: (N, 2), metres."""
    p_c = points @ euler_to_matrix(pose[3:]).T + pose[:3]
    return -F * p_c[:, [0, 2]] / (p_c[:, 1:2] - F)


def test_projection_table_rows_are_rotation_and_finite_difference_derivatives():
    """With the unit vectors as feature points and t = 0, the table exposes R and dR/dtheta."""
    angles = np.array([0.3, -1.1, 2.0])
    table = projection_table(np.eye(3), F)
    g = (table @ pose_features(np.concatenate([np.zeros(3), angles])[None])[0]).reshape(7, 3, 3)
    # Coordinates in table order: -f x_C, -f z_C, y_C - f; column j is the image of e_j.

    def unpack(rows: np.ndarray, shift: float) -> np.ndarray:
        return np.array([rows[0] / -F, rows[2] + shift, rows[1] / -F])

    np.testing.assert_allclose(unpack(g[0], F), euler_to_matrix(angles), atol=1e-15)
    for b in range(3):  # d p_C / d t_b = e_b for every point
        np.testing.assert_array_equal(unpack(g[1 + b], 0.0), np.outer(np.eye(3)[b], np.ones(3)))
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1e-6
        fd = (euler_to_matrix(angles + e) - euler_to_matrix(angles - e)) / 2e-6
        np.testing.assert_allclose(unpack(g[4 + k], 0.0), fd, atol=1e-9)


def test_projection_and_jacobian():
    pose = np.array([0.05, 1.2, -0.03, 0.3, -0.4, 1.1])
    h, jac, depth = pose_projection(pose, NON_COPLANAR, F)
    np.testing.assert_allclose(h.reshape(4, 2), image_of(pose, NON_COPLANAR), rtol=1e-13)
    p_c = NON_COPLANAR @ euler_to_matrix(pose[3:]).T + pose[:3]
    np.testing.assert_allclose(depth, p_c[:, 1] - F, rtol=1e-14)
    fd = np.empty_like(jac)
    for k in range(6):
        e = np.zeros(6)
        e[k] = 1e-7
        fd[:, k] = (
            pose_projection(pose + e, NON_COPLANAR, F)[0]
            - pose_projection(pose - e, NON_COPLANAR, F)[0]
        ) / 2e-7
    np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("points", [NON_COPLANAR, SQUARE], ids=["non_coplanar", "square"])
def test_recovers_known_pose_without_guess(points):
    rng = np.random.default_rng(2016)
    for _ in range(12):
        pose, rot = random_pose(rng)
        sol = solve_pose(image_of(pose, points), points, F)
        assert sol.converged
        assert sol.residual_rms < 1e-12
        np.testing.assert_allclose(sol.pose[:3], pose[:3], atol=1e-8)
        np.testing.assert_allclose(euler_to_matrix(sol.pose[3:]), rot, atol=1e-8)
        assert -np.pi / 2 <= sol.pose[4] <= np.pi / 2


def test_warm_start_converges_quickly():
    rng = np.random.default_rng(5)
    pose, _ = random_pose(rng)
    guess = pose + np.array([0.01, -0.02, 0.01, 0.05, -0.05, 0.05])
    sol = solve_pose(image_of(pose, NON_COPLANAR), NON_COPLANAR, F, initial_guess=guess)
    assert sol.converged and sol.iterations <= 10
    np.testing.assert_allclose(sol.pose[:3], pose[:3], atol=1e-9)


def test_noisy_image_gives_close_pose_and_plausible_residual():
    rng = np.random.default_rng(9)
    errors, residuals = [], []
    for _ in range(20):
        pose, _ = random_pose(rng)
        z = image_of(pose, NON_COPLANAR) + rng.normal(scale=PITCH, size=(4, 2))
        sol = solve_pose(z, NON_COPLANAR, F)
        assert sol.converged
        errors.append(np.linalg.norm(sol.pose[:3] - pose[:3]))
        residuals.append(sol.residual_rms / PITCH)
    # 1 px noise: 8 equations, 6 unknowns -> rms residual ~ sqrt(2/8) px; position within ~cm.
    assert 0.2 < np.median(residuals) < 1.0
    assert np.median(errors) < 0.01


def test_cold_solutions_are_memoised_by_exact_image():
    """The cold multi-start is solved once per exact image: a repeat returns an equal, unshared
    solution; a different image (one bit) is solved afresh; a cleared cache gives the same."""
    from capture_bench.sensing import photogrammetry

    rng = np.random.default_rng(21)
    pose, _ = random_pose(rng)
    z = image_of(pose, NON_COPLANAR) + rng.normal(scale=PITCH, size=(4, 2))
    first = solve_pose(z, NON_COPLANAR, F)
    first.pose[:] = 0.0  # a caller's edit must not reach the cache
    again = solve_pose(z, NON_COPLANAR, F)
    assert again.converged and np.linalg.norm(again.pose[:3] - pose[:3]) < 0.05  # not the zeros
    photogrammetry.clear_solve_cache()
    fresh = solve_pose(z, NON_COPLANAR, F)
    np.testing.assert_array_equal(fresh.pose, again.pose)
    assert (fresh.converged, fresh.iterations, fresh.residual_rms) == (
        again.converged,
        again.iterations,
        again.residual_rms,
    )
    nudged = z.copy()
    nudged[0, 0] = np.nextafter(nudged[0, 0], 1.0)
    assert not np.array_equal(solve_pose(nudged, NON_COPLANAR, F).pose, fresh.pose)


def test_primed_cold_solves_are_the_solves_of_each_image_alone():
    """cold_solves keeps the batch's solution of each image; solve_pose then returns it,
    equal to a fresh solve of that image alone (to rounding on any machine), and the memo
    grows by the images not yet kept."""
    from capture_bench.sensing import photogrammetry

    rng = np.random.default_rng(30)
    poses = [random_pose(rng)[0] for _ in range(4)]
    images = np.stack(
        [image_of(pose, NON_COPLANAR) + rng.normal(scale=PITCH, size=(4, 2)) for pose in poses]
    )
    photogrammetry.clear_solve_cache()
    photogrammetry.cold_solves(images, NON_COPLANAR, F)
    assert photogrammetry.solve_cache_size()[0] == 4
    primed = [solve_pose(image, NON_COPLANAR, F) for image in images]
    photogrammetry.cold_solves(images[:2], NON_COPLANAR, F)
    assert photogrammetry.solve_cache_size()[0] == 4
    photogrammetry.clear_solve_cache()
    for image, kept, pose in zip(images, primed, poses, strict=True):
        fresh = solve_pose(image, NON_COPLANAR, F)
        np.testing.assert_allclose(kept.pose, fresh.pose, rtol=1e-9, atol=1e-12)
        assert kept.converged == fresh.converged
        assert kept.converged and np.linalg.norm(kept.pose[:3] - pose[:3]) < 0.05


def test_shape_mismatch_raises():
    with pytest.raises(ValueError, match="image_points"):
        solve_pose(np.zeros((3, 2)), NON_COPLANAR, F)


def test_batched_projection_matches_single_pose():
    rng = np.random.default_rng(11)
    poses = np.array([random_pose(rng)[0] for _ in range(5)])
    table = projection_table(NON_COPLANAR, F)
    rj, depth = project_poses(poses, table, image_of(poses[0], NON_COPLANAR).T)
    for k, pose in enumerate(poses):
        h, jac, d = pose_projection(pose, NON_COPLANAR, F)
        residual = h - image_of(poses[0], NON_COPLANAR).reshape(8)
        np.testing.assert_allclose(rj[k, 0].T.reshape(8), residual, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(rj[k, 1:].transpose(2, 1, 0).reshape(8, 6), jac, rtol=1e-12)
        np.testing.assert_allclose(depth[k], d, rtol=1e-14)


@pytest.mark.parametrize("points", [NON_COPLANAR, SQUARE], ids=["non_coplanar", "square"])
def test_starts_run_together_as_they_would_alone(points):
    """The vectorised Levenberg-Marquardt: each start ends where it ends when run by itself."""
    rng = np.random.default_rng(3)
    pose, _ = random_pose(rng)
    z = image_of(pose, points) + rng.normal(scale=PITCH, size=(4, 2))
    table = projection_table(points, F)
    starts = np.array([pose + rng.normal(scale=0.3, size=6) for _ in range(8)])
    together = levenberg_marquardt(z.T, table, starts, 50, 1e-10)
    for k in range(len(starts)):
        alone = levenberg_marquardt(z.T, table, starts[k : k + 1], 50, 1e-10)
        np.testing.assert_array_equal(together[1][k], alone[1][0])  # converged
        np.testing.assert_allclose(together[0][k], alone[0][0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(together[3][k], alone[3][0], rtol=1e-9)
