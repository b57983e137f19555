"""Cold photogrammetry of many images at once: solve_pose_batch equals solve_pose image by image."""

from __future__ import annotations

import numpy as np
import pytest
from test_photogrammetry import (
    NON_COPLANAR,
    PITCH,
    SQUARE,
    F,
    image_of,
    random_pose,
)

from capture_bench.sensing import photogrammetry
from capture_bench.sensing.photogrammetry import (
    CUBE_ANGLES,
    CUBE_MATRICES,
    project_poses,
    projection_table,
    solve_pose,
    solve_pose_batch,
    translations_for_rotations,
)
from capture_bench.sim.rotations import euler_to_matrix


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


def assert_equals_solve_pose(images, points, **kwargs) -> tuple:
    """Equality, image by image, with the single-image cold solve; returns the batch.

    Convergence exactly; poses and residuals to rounding, and not the iteration count (which of
    two starts that reach the same pose wins can turn on the last bit): the batch stacks the LAPACK solves
    that solve_pose makes one at a time, and on some CPUs OpenBLAS rounds the two differently
    (bit for bit on the machine this was written on, ~1e-12 apart on another)."""
    poses, converged, iterations, rms = solve_pose_batch(images, points, F, **kwargs)
    m = len(images)
    assert poses.shape == (m, 6) and poses.dtype == float
    assert converged.shape == (m,) and converged.dtype == bool
    assert iterations.shape == (m,) and np.issubdtype(iterations.dtype, np.integer)
    assert rms.shape == (m,) and rms.dtype == float
    photogrammetry.clear_solve_cache()
    for i in range(m):
        sol = solve_pose(images[i], points, F, **kwargs)
        np.testing.assert_allclose(poses[i], sol.pose, rtol=1e-8, atol=1e-8)  # m, rad
        assert bool(converged[i]) == sol.converged
        np.testing.assert_allclose(rms[i], sol.residual_rms, rtol=1e-9, atol=1e-12)  # nan == nan
    return poses, converged, iterations, rms


def starts_behind_lens(image: np.ndarray, points: np.ndarray) -> int:
    """How many of the 24 cold starts of this image have a point at or behind the lens."""
    rotated = np.einsum("kij,nj->kni", CUBE_MATRICES, points)
    t = translations_for_rotations(image, rotated, F)
    _, depth = project_poses(np.concatenate([t, CUBE_ANGLES], axis=1), projection_table(points, F))
    return int((depth <= 0).any(axis=1).sum())


@pytest.mark.parametrize("points", [NON_COPLANAR, SQUARE], ids=["non_coplanar", "square"])
def test_batch_equals_solve_pose_image_by_image(points):
    """50 noisy images (enough rows that a round's lambdas are tried in batches, and images come
    down to one row while others still have many), some close enough that starts go behind the
    lens: every field equals solve_pose's exactly."""
    images = noisy_images(points, 50, seed=7, close=8)
    assert sum(starts_behind_lens(z, points) > 0 for z in images[:8]) >= 4
    _, converged, _, rms = assert_equals_solve_pose(images, points)
    assert converged.all() and np.median(rms) < PITCH


def test_batch_equals_solve_pose_when_no_start_converges():
    """Two iterations per start: nothing converges, and the batch still keeps what solve_pose
    keeps (the least residual of all starts)."""
    images = noisy_images(NON_COPLANAR, 6, seed=8, close=2)
    _, converged, iterations, _ = assert_equals_solve_pose(images, NON_COPLANAR, max_iterations=2)
    assert not converged.any() and (iterations <= 2).all()


def test_batch_equals_solve_pose_on_an_image_nothing_fits():
    """An image no pose explains (points swapped pairwise, 100 px noise), next to ordinary ones."""
    rng = np.random.default_rng(10)
    images = noisy_images(NON_COPLANAR, 4, seed=11)
    images[1] = images[1][[1, 0, 3, 2]] + rng.normal(scale=100 * PITCH, size=(4, 2))
    _, _, _, rms = assert_equals_solve_pose(images, NON_COPLANAR)
    assert rms[1] > 10 * PITCH


def test_single_image_and_empty_batch():
    images = noisy_images(SQUARE, 1, seed=12)
    assert_equals_solve_pose(images, SQUARE)
    poses, converged, iterations, rms = solve_pose_batch(np.empty((0, 4, 2)), SQUARE, F)
    assert poses.shape == (0, 6) and converged.shape == iterations.shape == rms.shape == (0,)


@pytest.mark.parametrize("points", [NON_COPLANAR, SQUARE], ids=["non_coplanar", "square"])
def test_batch_recovers_known_poses_from_noiseless_images(points):
    rng = np.random.default_rng(2016)
    truth = [random_pose(rng) for _ in range(16)]
    images = np.array([image_of(pose, points) for pose, _ in truth])
    poses, converged, _, rms = solve_pose_batch(images, points, F)
    assert converged.all() and (rms < 1e-12).all()
    for (pose, rot), found in zip(truth, poses):
        np.testing.assert_allclose(found[:3], pose[:3], atol=1e-8)
        np.testing.assert_allclose(euler_to_matrix(found[3:]), rot, atol=1e-8)
        assert -np.pi / 2 <= found[4] <= np.pi / 2


def test_batch_shape_mismatch_raises():
    with pytest.raises(ValueError, match="images"):
        solve_pose_batch(np.zeros((2, 3, 2)), NON_COPLANAR, F)
    with pytest.raises(ValueError, match="images"):
        solve_pose_batch(np.zeros((4, 2)), NON_COPLANAR, F)


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
