"""Three-point (P3P) poses and the estimator's three-point initialisation.

The images come from the project's own eq. 2 (`photogrammetry.pose_projection`), so the P3P
call's camera convention (`capture_bench.sensing.p3p`, OpenCV's frame) is checked against it.
"""

from __future__ import annotations

import numpy as np
import pytest

from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.estimator import STATUSES, TargetEstimator
from capture_bench.sensing.p3p import (
    candidate_residuals,
    consensus_candidate,
    pick_candidate,
    refine_pose,
    three_point_poses,
)
from capture_bench.sensing.photogrammetry import pose_projection, solve_poses
from capture_bench.sim.target_motion import FEATURE_POINTS

F = 0.008
PITCH = 3.75e-6
NOISE_PX = 1.0
MAX_RESIDUAL = 5.0 * NOISE_PX * PITCH  # the estimator's acceptance residual at 1 px
# Three points carry no redundancy: at 1 px the picked three-point position error (RMS over
# poses 0.8-1.6 m away) is 1.1-2.2 times the four-point solve's (about 8 mm) on the same frames
# for the non-coplanar points, by hidden point (seed 1, 150 poses); the bound leaves room for
# other draws.
THREE_POINT_ERROR_RATIO = 3.0


def image(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Eq. 2 image (N, 2) of the points for a pose, metres (the project's projection)."""
    h, _, _ = pose_projection(pose, points, F)
    return h.reshape(-1, 2)


def random_pose(rng: np.random.Generator) -> np.ndarray:
    """A target 0.8-1.6 m in front of the camera, Euler angles within 1 rad."""
    t = [rng.uniform(-0.1, 0.1), rng.uniform(0.8, 1.6), rng.uniform(-0.1, 0.1)]
    return np.concatenate([t, rng.uniform(-1.0, 1.0, 3)])


def without(image_points: np.ndarray, hidden: int) -> np.ndarray:
    """The image with point ``hidden`` not seen (NaN row)."""
    out = image_points.copy()
    out[hidden] = np.nan
    return out


@pytest.mark.parametrize("name", sorted(FEATURE_POINTS))
@pytest.mark.parametrize("hidden", range(4))
def test_candidates_hold_the_true_pose(name: str, hidden: int) -> None:
    points = FEATURE_POINTS[name]
    keep = [i for i in range(4) if i != hidden]
    rng = np.random.default_rng(hidden)
    for _ in range(10):
        pose = random_pose(rng)
        uv = image(pose, points)
        candidates = three_point_poses(uv[keep], points[keep], F)
        assert 1 <= candidates.shape[0] <= 4
        error = np.abs(candidates - pose).max(axis=1) / np.abs(pose).max()
        assert error.min() < 1e-6
        # Every candidate images the three points where they are (that is what P3P solves).
        for c in candidates:
            np.testing.assert_allclose(image(c, points)[keep], uv[keep], rtol=0, atol=1e-12)


def test_three_points_validated() -> None:
    points = FEATURE_POINTS["non_coplanar"]
    with pytest.raises(ValueError, match="image_points"):
        three_point_poses(np.zeros((4, 2)), points, F)
    with pytest.raises(ValueError, match="finite"):
        three_point_poses(np.full((3, 2), np.nan), points[:3], F)


def test_three_point_error_within_bound_of_four_point() -> None:
    """1 px noise: the three-point estimate (picked by a second noisy frame of all four points)
    against the four-point solve of the same frames, per hidden point."""
    points = FEATURE_POINTS["non_coplanar"]
    rng = np.random.default_rng(1)
    four = []
    three: list[dict[int, float]] = [{} for _ in range(4)]  # frame -> error, per hidden point
    for frame in range(150):
        pose = random_pose(rng)
        uv = image(pose, points)
        z = uv + rng.normal(size=(4, 2)) * NOISE_PX * PITCH
        z_next = uv + rng.normal(size=(4, 2)) * NOISE_PX * PITCH
        four.append(np.linalg.norm(solve_poses(z[None], points, F)[0].pose[:3] - pose[:3]))
        for hidden in range(4):
            keep = [i for i in range(4) if i != hidden]
            candidates = three_point_poses(z[keep], points[keep], F)
            k = pick_candidate(candidate_residuals(candidates, z_next, points, F), MAX_RESIDUAL)
            if k is not None:
                three[hidden][frame] = float(np.linalg.norm(candidates[k, :3] - pose[:3]))
    for errors in three:
        assert len(errors) >= 120  # the fourth point tells the candidates apart in most frames
        rms_three = np.sqrt(np.mean(np.square(list(errors.values()))))
        rms_four = np.sqrt(np.mean(np.square([four[i] for i in errors])))
        assert rms_three <= THREE_POINT_ERROR_RATIO * rms_four


def moving_poses(steps: int) -> np.ndarray:
    """(steps, 6) poses of a target moving at constant rates, 1.2 m away, 0.05 s steps."""
    start = np.array([0.05, 1.2, -0.03, 0.3, -0.2, 0.5])
    rates = np.array([0.02, -0.01, 0.015, 0.05, 0.04, -0.06])
    return start + 0.05 * np.arange(steps)[:, None] * rates


def test_next_frame_with_another_point_picks_the_true_candidate() -> None:
    points = FEATURE_POINTS["non_coplanar"]
    poses = moving_poses(2)
    candidates = three_point_poses(image(poses[0], points)[:3], points[:3], F)
    assert candidates.shape[0] >= 2  # an ambiguity to resolve
    truth = int(np.argmin(np.abs(candidates - poses[0]).max(axis=1)))
    nxt = without(image(poses[1], points), 2)  # point 3 appears, point 2 is hidden
    residuals = candidate_residuals(candidates, nxt, points, F)
    assert pick_candidate(residuals, MAX_RESIDUAL) == truth
    refined, converged, rms = refine_pose(candidates[truth], nxt, points, F)
    assert converged and rms < 1e-12
    np.testing.assert_allclose(refined, poses[1], rtol=0, atol=1e-9)


def test_same_three_points_do_not_tell_candidates_apart() -> None:
    """Every candidate images the same three points identically, so a later frame of those
    three scores them alike: no pick (the estimator then waits for another point)."""
    points = FEATURE_POINTS["non_coplanar"]
    poses = moving_poses(2)
    candidates = three_point_poses(image(poses[0], points)[:3], points[:3], F)
    nxt = without(image(poses[1], points), 3)
    residuals = candidate_residuals(candidates, nxt, points, F)
    np.testing.assert_allclose(residuals, residuals[0], rtol=1e-9)
    assert pick_candidate(residuals, np.inf) is None


PRIOR_SD = np.array([0.05] * 3 + [0.2] * 3)  # the filter's prior standard deviations of the pose


def test_consensus_candidate() -> None:
    base = np.array([0.0, 1.0, 0.0, 0.1, 0.2, 3.1])
    near = base + [0.01, -0.02, 0.0, 0.1, -0.1, 0.0]
    near[5] -= 2.0 * np.pi  # 3.1 - 2 pi: the same angle wrapped
    mid = 0.5 * (base + near)
    mid[5] = base[5]
    assert consensus_candidate(base[None], PRIOR_SD) == 0
    assert consensus_candidate(np.stack([base, near]), PRIOR_SD) == 0  # a tie: the first
    assert consensus_candidate(np.stack([base, mid, near]), PRIOR_SD) == 1  # the medoid
    far = base + [0.0, 0.0, 0.0, 0.0, 0.3, 0.0]
    assert consensus_candidate(np.stack([base, far]), PRIOR_SD) is None
    # far is within the spread of mid, base is not within it of far: mid is the only centre
    mid_far = base + [0.0, 0.0, 0.0, 0.0, 0.15, 0.0]
    assert consensus_candidate(np.stack([base, mid_far, far]), PRIOR_SD) == 1


# A pose whose P3P candidates from points 0, 1 and 3 lie within PRIOR_SD of each other
# (found by search; about 1 in 1600 random poses has agreeing candidates).
AGREEING_POSE = np.array([-0.083, 0.989, 0.06, 0.164, -0.812, -0.134])


def test_estimator_starts_at_once_when_candidates_agree() -> None:
    points = FEATURE_POINTS["non_coplanar"]
    uv = image(AGREEING_POSE, points)
    candidates = three_point_poses(uv[[0, 1, 3]], points[[0, 1, 3]], F)
    assert candidates.shape[0] == 2 and consensus_candidate(candidates, PRIOR_SD) == 0
    default, three = estimator(1), estimator(1, min_init_markers=3)
    assert default.update(without(uv, 2)[None], 0.05).status_names() == ["initialising"]
    assert three.update(without(uv, 2)[None], 0.05).status_names() == ["ok"]
    np.testing.assert_array_equal(three.x[0, :6], candidates[0])
    for _ in range(5):  # complete frames: the filter runs on, photogrammetry is not asked
        assert three.update(uv[None], 0.05).status_names() == ["ok"]
    assert np.abs(three.x[0, :3] - AGREEING_POSE[:3]).max() < 1e-6


CAMERA = CameraModel(position=np.zeros(3), rotation=np.eye(3), focal_length=F, pixel_pitch=PITCH)


def estimator(n: int, **more: object) -> TargetEstimator:
    return TargetEstimator(n, CAMERA, FEATURE_POINTS["non_coplanar"], noise_px=1.0, **more)  # type: ignore[arg-type]


def test_estimator_starts_from_three_points_and_the_next_frame() -> None:
    points = FEATURE_POINTS["non_coplanar"]
    poses = moving_poses(3)
    frames = [without(image(poses[0], points), 3), without(image(poses[1], points), 2)]
    frames.append(without(image(poses[2], points), 2))
    default, three = estimator(1), estimator(1, min_init_markers=3)
    names = []
    for k, frame in enumerate(frames):
        assert default.update(frame[None], 0.05).status_names() == ["initialising"]
        out = three.update(frame[None], 0.05)
        names.append(out.status_names()[0])
        if k == 1:  # started at the next frame, from its refined pick
            np.testing.assert_allclose(three.x[0, :6], poses[1], rtol=0, atol=1e-9)
    assert names == ["initialising", "ok", "ok"]
    assert not default.initialised[0] and three.initialised[0]


def test_estimator_rows_start_alike_in_a_batch() -> None:
    """The many-row path starts a row from three points as the one-row path does, and a row's
    held candidates move with it (snapshot, restore)."""
    points = FEATURE_POINTS["non_coplanar"]
    poses = moving_poses(2)
    frames = np.stack([without(image(poses[0], points), 3), without(image(poses[1], points), 2)])
    one, many = estimator(1, min_init_markers=3), estimator(3, min_init_markers=3)
    for frame in frames:
        batch = np.stack([frame, np.full((4, 2), np.nan), frame])
        a, b = one.update(frame[None], 0.05), many.update(batch, 0.05)
        if not one.initialised[0]:  # candidates held: carry them to a fresh estimator
            moved = estimator(2, min_init_markers=3)
            moved.restore([1], many.snapshot([2]))
            assert np.isfinite(moved.snapshot([1]).candidates[:, :2]).all()
    assert a.status_names() == ["ok"] and b.status_names() == ["ok", "initialising", "ok"]
    np.testing.assert_array_equal(many.x[[0, 2]], np.repeat(one.x, 2, axis=0))
    moved.update(np.stack([np.full((4, 2), np.nan), frames[1]]), 0.05)
    np.testing.assert_array_equal(moved.x[1], one.x[0])
    assert np.isnan(many.snapshot([0, 2]).candidates).all()  # dropped at the start
    many.reset()
    assert np.isnan(many.snapshot([0, 1, 2]).candidates).all()


def noisy_sequence(rng: np.random.Generator, steps: int, partial: bool) -> np.ndarray:
    """(steps, 4, 2) noisy frames of the moving target: some lost (NaN); with ``partial``,
    some missing one point."""
    points = FEATURE_POINTS["non_coplanar"]
    frames = []
    for pose in moving_poses(steps):
        z = image(pose, points) + rng.normal(size=(4, 2)) * PITCH
        u = rng.uniform()
        if u < 0.2:
            z[:] = np.nan
        elif partial and u < 0.5:
            z[rng.integers(4)] = np.nan
        frames.append(z)
    return np.array(frames)


def run(est: TargetEstimator, images: np.ndarray) -> list[tuple[np.ndarray, ...]]:
    """Every step's estimates and state of an estimator over (steps, n, 4, 2) images."""
    out = []
    for z in images:
        e = est.update(z, 0.05)
        out.append((e.position, e.velocity, e.covariance, e.valid, e.status, est.x.copy()))
    return out


@pytest.mark.parametrize("n", [1, 3])
def test_option_off_and_complete_frames_unchanged(n: int) -> None:
    """The default (4) is min_init_markers left out; with every frame complete or lost, the
    three-point option changes nothing either; bit for bit, one row and many."""
    rng = np.random.default_rng(7)
    complete = np.stack([noisy_sequence(rng, 30, False) for _ in range(n)], axis=1)
    partial = np.stack([noisy_sequence(rng, 30, True) for _ in range(n)], axis=1)
    for images, options in ((complete, (4, 3)), (partial, (4,))):
        reference = run(estimator(n), images)
        for m in options:
            for a, b in zip(reference, run(estimator(n, min_init_markers=m), images), strict=True):
                for x, y in zip(a, b, strict=True):
                    np.testing.assert_array_equal(x, y)


def test_min_init_markers_validated() -> None:
    with pytest.raises(ValueError, match="min_init_markers"):
        estimator(1, min_init_markers=2)
    assert "initialising" in STATUSES


def test_a_diverged_filter_restarts_from_three_points() -> None:
    points = FEATURE_POINTS["non_coplanar"]
    before = AGREEING_POSE + [0.4, 0.3, 0.2, 0.0, 0.0, 0.0]  # where the filter settles, 54 cm off
    default, three = estimator(1), estimator(1, min_init_markers=3)
    for est in (default, three):
        for _ in range(40):  # settled there
            assert est.update(image(before, points)[None], 0.05).status_names() == ["ok"]
    # The target is now elsewhere and shows three points: the NIS diverges the filter, and only
    # the three-point start brings it back (its candidates agree), at the true pose, on the step
    # the divergence is found (so no step reports "diverged").
    frame = without(image(AGREEING_POSE, points), 2)[None]
    names = {"default": [], "three": []}
    for _ in range(10):
        names["default"].append(default.update(frame, 0.05).status_names()[0])
        names["three"].append(three.update(frame, 0.05).status_names()[0])
    assert names["three"][-1] == "ok" and three.reinitialisations[0] == 1
    np.testing.assert_allclose(three.x[0, :3], AGREEING_POSE[:3], rtol=0, atol=1e-6)
    assert names["default"][-1] == "diverged" and default.reinitialisations[0] == 0
