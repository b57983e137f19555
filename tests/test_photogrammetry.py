"""Photogrammetry (eqs. 1-2): analytic Jacobian, pose recovery, many images at once."""

from __future__ import annotations

import numpy as np
import pytest

from capture_bench.sensing import photogrammetry
from capture_bench.sensing.photogrammetry import (
    CUBE_ANGLES,
    CUBE_MATRICES,
    PoseSolution,
    levenberg_marquardt,
    pose_features,
    pose_projection,
    project_poses,
    projection_table,
    solve_poses,
    translations_for_rotations,
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


def assert_same_solution(a: PoseSolution, b: PoseSolution) -> None:
    """Convergence exactly; pose and residual to rounding, and not the iteration count (which of
    two starts that reach the same pose wins can turn on the last bit): a solve of several
    images stacks the LAPACK solves that a solve of one image makes alone, and on some CPUs
    OpenBLAS rounds the two differently (bit for bit on the machine this was written on,
    ~1e-12 apart on another)."""
    np.testing.assert_allclose(a.pose, b.pose, rtol=1e-8, atol=1e-8)  # m, rad
    assert a.converged == b.converged
    np.testing.assert_allclose(a.residual_rms, b.residual_rms, rtol=1e-9, atol=1e-12)  # nan == nan


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
        (sol,) = solve_poses(image_of(pose, points)[None], points, F)
        assert sol.converged
        assert sol.residual_rms < 1e-12
        np.testing.assert_allclose(sol.pose[:3], pose[:3], atol=1e-8)
        np.testing.assert_allclose(euler_to_matrix(sol.pose[3:]), rot, atol=1e-8)
        assert -np.pi / 2 <= sol.pose[4] <= np.pi / 2


def test_warm_start_converges_quickly():
    rng = np.random.default_rng(5)
    pose, _ = random_pose(rng)
    guess = pose + np.array([0.01, -0.02, 0.01, 0.05, -0.05, 0.05])
    (sol,) = solve_poses(image_of(pose, NON_COPLANAR)[None], NON_COPLANAR, F, guess[None])
    assert sol.converged and sol.iterations <= 10
    np.testing.assert_allclose(sol.pose[:3], pose[:3], atol=1e-9)


def test_noisy_image_gives_close_pose_and_plausible_residual():
    rng = np.random.default_rng(9)
    errors, residuals = [], []
    for _ in range(20):
        pose, _ = random_pose(rng)
        z = image_of(pose, NON_COPLANAR) + rng.normal(scale=PITCH, size=(4, 2))
        (sol,) = solve_poses(z[None], NON_COPLANAR, F)
        assert sol.converged
        errors.append(np.linalg.norm(sol.pose[:3] - pose[:3]))
        residuals.append(sol.residual_rms / PITCH)
    # 1 px noise: 8 equations, 6 unknowns -> rms residual ~ sqrt(2/8) px; position within ~cm.
    assert 0.2 < np.median(residuals) < 1.0
    assert np.median(errors) < 0.01


def test_cold_solutions_are_memoised_by_exact_image():
    """The cold multi-start is solved once per exact image: a repeat returns an equal, unshared
    solution; a different image (one bit) is solved afresh; a cleared cache gives the same."""
    rng = np.random.default_rng(21)
    pose, _ = random_pose(rng)
    z = image_of(pose, NON_COPLANAR) + rng.normal(scale=PITCH, size=(4, 2))
    (first,) = solve_poses(z[None], NON_COPLANAR, F)
    first.pose[:] = 0.0  # a caller's edit must not reach the cache
    (again,) = solve_poses(z[None], NON_COPLANAR, F)
    assert again.converged and np.linalg.norm(again.pose[:3] - pose[:3]) < 0.05  # not the zeros
    photogrammetry.clear_solve_cache()
    (fresh,) = solve_poses(z[None], NON_COPLANAR, F)
    np.testing.assert_array_equal(fresh.pose, again.pose)
    assert (fresh.converged, fresh.iterations, fresh.residual_rms) == (
        again.converged,
        again.iterations,
        again.residual_rms,
    )
    nudged = z.copy()
    nudged[0, 0] = np.nextafter(nudged[0, 0], 1.0)
    assert not np.array_equal(solve_poses(nudged[None], NON_COPLANAR, F)[0].pose, fresh.pose)


def test_primed_cold_solves_are_the_solves_of_each_image_alone():
    """A cold solve of several images keeps each image's solution; a later solve of one of
    them returns it, equal to a fresh solve of that image alone, and the memo grows by the
    images not yet kept."""
    rng = np.random.default_rng(30)
    poses = [random_pose(rng)[0] for _ in range(4)]
    images = np.stack(
        [image_of(pose, NON_COPLANAR) + rng.normal(scale=PITCH, size=(4, 2)) for pose in poses]
    )
    photogrammetry.clear_solve_cache()
    solve_poses(images, NON_COPLANAR, F)
    assert photogrammetry.solve_cache_size()[0] == 4
    primed = [solve_poses(image[None], NON_COPLANAR, F)[0] for image in images]
    solve_poses(images[:2], NON_COPLANAR, F)
    assert photogrammetry.solve_cache_size()[0] == 4
    photogrammetry.clear_solve_cache()
    for image, kept, pose in zip(images, primed, poses, strict=True):
        (fresh,) = solve_poses(image[None], NON_COPLANAR, F)
        assert_same_solution(kept, fresh)
        assert kept.converged and np.linalg.norm(kept.pose[:3] - pose[:3]) < 0.05


def test_shape_mismatch_raises():
    with pytest.raises(ValueError, match="images"):
        solve_poses(np.zeros((1, 3, 2)), NON_COPLANAR, F)
    with pytest.raises(ValueError, match="images"):
        solve_poses(np.zeros((4, 2)), NON_COPLANAR, F)
    with pytest.raises(ValueError, match="guesses"):
        solve_poses(np.zeros((2, 4, 2)), NON_COPLANAR, F, np.zeros((1, 6)))


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


# -- many images at once: each image's solution is its solution alone ----------------------------


def noisy_images(points: np.ndarray, m: int, seed: int, close: int = 0) -> np.ndarray:
    """m images of random poses with 1 px noise; the first ``close`` have the target 0.05-0.3 m
    away, where many of the 24 starts put a point behind the lens."""
    rng = np.random.default_rng(seed)
    images = []
    for i in range(m):
        pose, _ = random_pose(rng)
        if i < close:
            pose[1] = rng.uniform(0.05, 0.3)
        images.append(image_of(pose, points) + rng.normal(scale=PITCH, size=(len(points), 2)))
    return np.array(images)


def assert_equals_each_image_alone(images, points, guesses=None, **kwargs) -> list[PoseSolution]:
    """solve_poses of all the images, fresh, equals solve_poses of each image alone, fresh
    (`assert_same_solution`); returns the solutions of all of them."""
    photogrammetry.clear_solve_cache()
    together = solve_poses(images, points, F, guesses, **kwargs)
    assert len(together) == len(images)
    for i, solution in enumerate(together):
        photogrammetry.clear_solve_cache()
        guess = None if guesses is None else guesses[i : i + 1]
        (alone,) = solve_poses(images[i : i + 1], points, F, guess, **kwargs)
        assert_same_solution(solution, alone)
        assert solution.pose.shape == (6,) and solution.pose.dtype == float
    return together


def starts_behind_lens(image: np.ndarray, points: np.ndarray) -> int:
    """How many of the 24 cold starts of this image have a point at or behind the lens."""
    rotated = np.einsum("kij,nj->kni", CUBE_MATRICES, points)
    t = translations_for_rotations(image, rotated, F)
    _, depth = project_poses(np.concatenate([t, CUBE_ANGLES], axis=1), projection_table(points, F))
    return int((depth <= 0).any(axis=1).sum())


@pytest.mark.parametrize("points", [NON_COPLANAR, SQUARE], ids=["non_coplanar", "square"])
def test_cold_images_together_equal_each_image_alone(points):
    """50 noisy images (enough rows that a round's lambdas are tried in batches, and images come
    down to one row while others still have many), some close enough that starts go behind the
    lens."""
    images = noisy_images(points, 50, seed=7, close=8)
    assert sum(starts_behind_lens(z, points) > 0 for z in images[:8]) >= 4
    solutions = assert_equals_each_image_alone(images, points)
    assert all(s.converged for s in solutions)
    assert np.median([s.residual_rms for s in solutions]) < PITCH


@pytest.mark.parametrize("points", [NON_COPLANAR, SQUARE], ids=["non_coplanar", "square"])
def test_warm_and_cold_images_together_equal_each_image_alone(points):
    """Images with guesses near their pose, far from it, behind the lens (warm starts that fail
    and fall back to the cold multi-start) and without one (a row of NaN), in one call."""
    rng = np.random.default_rng(14)
    truth = [random_pose(rng)[0] for _ in range(40)]
    images = np.array(
        [image_of(pose, points) + rng.normal(scale=PITCH, size=(4, 2)) for pose in truth]
    )
    guesses = (
        np.array(truth)
        + rng.normal(scale=[[0.01], [0.5], [2.0], [0.0]], size=(4, 6))[np.arange(40) % 4]
    )
    guesses[3::8, 1] = -1.0  # behind the lens
    guesses[7::8] = np.nan  # cold
    solutions = assert_equals_each_image_alone(images, points, guesses)
    warm_ok = [i for i, s in enumerate(solutions) if s.converged and s.iterations <= 10]
    assert len(warm_ok) >= 10
    for kwargs in ({"max_iterations": 3}, {"max_iterations": 8}):  # some warm starts fail
        assert_equals_each_image_alone(images, points, guesses, **kwargs)


def test_cold_images_together_when_no_start_converges():
    """Two iterations per start: nothing converges, and each image keeps what it keeps alone
    (the least residual of all starts)."""
    images = noisy_images(NON_COPLANAR, 6, seed=8, close=2)
    solutions = assert_equals_each_image_alone(images, NON_COPLANAR, max_iterations=2)
    assert not any(s.converged for s in solutions)
    assert all(s.iterations <= 2 for s in solutions)


def test_images_together_with_an_image_nothing_fits():
    """An image no pose explains (points swapped pairwise, 100 px noise), next to ordinary ones."""
    rng = np.random.default_rng(10)
    images = noisy_images(NON_COPLANAR, 4, seed=11)
    images[1] = images[1][[1, 0, 3, 2]] + rng.normal(scale=100 * PITCH, size=(4, 2))
    solutions = assert_equals_each_image_alone(images, NON_COPLANAR)
    assert solutions[1].residual_rms > 10 * PITCH


def test_no_images():
    assert solve_poses(np.empty((0, 4, 2)), SQUARE, F) == []
    assert solve_poses(np.empty((0, 4, 2)), SQUARE, F, np.empty((0, 6))) == []


def test_solutions_are_new_objects():
    """Every call returns new solutions (the memo's stay untouched), warm or cold."""
    images = noisy_images(NON_COPLANAR, 2, seed=15)
    first = solve_poses(images, NON_COPLANAR, F)
    guesses = np.array([first[0].pose, np.full(6, np.nan)])
    again = solve_poses(images, NON_COPLANAR, F, guesses)
    assert all(a is not b and a.pose is not b.pose for a, b in zip(first, again, strict=True))
    kept = again[1].pose.copy()
    first[1].pose[:] = 0.0
    np.testing.assert_array_equal(solve_poses(images[1:], NON_COPLANAR, F)[0].pose, kept)


@pytest.mark.parametrize("points", [NON_COPLANAR, SQUARE], ids=["non_coplanar", "square"])
def test_images_together_recover_known_poses_from_noiseless_images(points):
    rng = np.random.default_rng(2016)
    truth = [random_pose(rng) for _ in range(16)]
    images = np.array([image_of(pose, points) for pose, _ in truth])
    solutions = solve_poses(images, points, F)
    for (pose, rot), found in zip(truth, solutions, strict=True):
        assert found.converged and found.residual_rms < 1e-12
        np.testing.assert_allclose(found.pose[:3], pose[:3], atol=1e-8)
        np.testing.assert_allclose(euler_to_matrix(found.pose[3:]), rot, atol=1e-8)
        assert -np.pi / 2 <= found.pose[4] <= np.pi / 2


def test_project_poses_alone_rows_round_as_a_call_with_that_pose_alone():
    """``alone`` rows come out as project_poses of that pose by itself (a matrix-vector product);
    the others as rows of a matrix-matrix product, even when only one of them is evaluated."""
    rng = np.random.default_rng(13)
    poses = np.array([random_pose(rng)[0] for _ in range(40)])
    table = projection_table(NON_COPLANAR, F)
    together = project_poses(poses, table)[0]  # matrix-matrix: every row as in any other
    alone_each = np.array([project_poses(p[None], table)[0][0] for p in poses])
    assert not np.array_equal(together, alone_each)  # the two products do round differently
    mask = np.arange(40) % 3 == 0
    mixed = project_poses(poses, table, alone=mask)[0]
    np.testing.assert_array_equal(mixed[mask], alone_each[mask])
    np.testing.assert_array_equal(mixed[~mask], together[~mask])
    one = project_poses(poses[:1], table, alone=np.array([False]))[0]
    np.testing.assert_array_equal(one[0], together[0])
    for k in (1, 2, 40):  # both layouts of the element-wise part (5 k rows: 5 to 200)
        np.testing.assert_array_equal(
            project_poses(poses[:k].repeat(5, axis=0), table, alone=np.ones(5 * k, dtype=bool))[0],
            alone_each[:k].repeat(5, axis=0),
        )
