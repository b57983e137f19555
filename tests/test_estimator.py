"""EKF (eqs. 3-7) and the estimator pipeline (photogrammetry -> EKF -> global frame, eqs. 11-12),
the estimator at n = 1 (`TargetEstimator(1, ...)`, one episode)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest
from references.scalar_estimator import TargetEKF

from capture_bench.sensing.camera import Camera, CameraModel, Frame
from capture_bench.sensing.ekf import (
    POSE_INDEX,
    default_initial_covariance,
    measurement,
    measurement_jacobian,
    measurement_sigma,
    process_noise,
    state_transition,
    transition_matrices,
)
from capture_bench.sensing.estimator import (
    BLOCK_ORDER,
    DIVERGENCE_FRAMES,
    NOISE_FLOOR_PX,
    FilterRows,
    TargetEstimator,
)
from capture_bench.sensing.photogrammetry import pose_projection
from capture_bench.sim.rotations import euler_to_matrix

F = 0.008
PITCH = 3.75e-6
DT = 0.05
FEATURES = np.array([(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.05)], dtype=float)
R_GT = euler_to_matrix([0.2, 0.1, -0.3])  # constant target attitude in the global frame


def camera_model() -> CameraModel:
    """The default placement: about 1.2 m from the workspace, looking at it."""
    return CameraModel.looking_at((0.45, -1.2, 0.45), (0.45, 0.0, 0.4))


def markers(position: np.ndarray) -> np.ndarray:
    """Feature points in the global frame for a target at ``position`` (global, m)."""
    return position + FEATURES @ R_GT.T


def images_of(frame: Frame | np.ndarray | None) -> np.ndarray:
    """The estimator's images (1, 4, 2) of one frame (or image (4, 2)); NaN: no frame."""
    if frame is None:
        return np.full((1, 4, 2), np.nan)
    image = frame.image_points if isinstance(frame, Frame) else frame
    return np.asarray(image, dtype=float).reshape(1, 4, 2)


def one_row(model: CameraModel, **kwargs: object) -> TargetEstimator:
    """The estimator of one episode."""
    return TargetEstimator(1, model, FEATURES, **kwargs)  # type: ignore[arg-type]


def dts(dt: float = DT) -> np.ndarray:
    return np.full(1, dt)


def test_transition_matrices_are_eqs_4_5():
    a, b = transition_matrices(0.1)
    x = np.arange(12.0)
    ax = a @ x
    np.testing.assert_allclose(ax[0::2], x[0::2] + 0.1 * x[1::2])  # position += t_s * rate
    np.testing.assert_allclose(ax[1::2], x[1::2])
    np.testing.assert_allclose(b[0::2], 0.005 * np.eye(6))  # t_s^2 / 2
    np.testing.assert_allclose(b[1::2], 0.1 * np.eye(6))


def test_process_noise_is_the_matrix_product_bit_for_bit():
    """``process_noise`` writes out ``B @ Q @ B.T`` (eq. 5): the same floats, for any t_s."""
    rng = np.random.default_rng(0)
    for dt in [0.0, DT, 0.1, 1e-300, 1e3, *rng.uniform(0.0, 0.2, 500)]:
        variances = (rng.uniform(1e-4, 1.0) ** 2,) * 3 + (rng.uniform(1e-4, 1.0) ** 2,) * 3
        a, b = transition_matrices(dt)
        expected = b @ np.diag(variances) @ b.T
        got = process_noise(dt, variances)
        assert got.tobytes() == expected.tobytes(), dt
        reference = np.eye(12)
        reference[[0, 2, 4, 6, 8, 10], [1, 3, 5, 7, 9, 11]] = dt  # eq. 4
        assert state_transition(dt).tobytes() == a.tobytes() == reference.tobytes()


def test_measurement_jacobian_matches_finite_differences():
    x = np.array([0.05, 0.01, 1.2, -0.02, -0.03, 0.0, 0.3, 0.1, -0.4, 0.0, 1.1, -0.2])
    h_mat = measurement_jacobian(x, FEATURES, F)
    assert h_mat.shape == (8, 12)
    fd = np.empty((8, 12))
    for k in range(12):
        e = np.zeros(12)
        e[k] = 1e-7
        fd[:, k] = (measurement(x + e, FEATURES, F) - measurement(x - e, FEATURES, F)) / 2e-7
    np.testing.assert_allclose(h_mat, fd, rtol=1e-6, atol=1e-12)
    assert np.all(h_mat[:, 1::2] == 0.0)  # the rates do not enter eq. 2


def test_filter_h_and_H_are_eq_2_and_its_jacobian():
    """The arrays the reference EKF (``references.scalar_estimator``, against which the
    estimator's rows are checked) hands to filterpy: eq. 2 by hand and central differences of
    it."""
    x = np.array([0.05, 0.01, 1.2, -0.02, -0.03, 0.0, 0.3, 0.1, -0.4, 0.0, 1.1, -0.2])
    ekf = TargetEKF(FEATURES, focal_length=F, pixel_pitch=PITCH)

    def by_hand(state: np.ndarray) -> np.ndarray:
        p_c = FEATURES @ euler_to_matrix(state[6::2]).T + state[0:6:2]
        return (-F * p_c[:, [0, 2]] / (p_c[:, 1:2] - F)).reshape(8)

    h_mat = ekf.jacobian(x).copy()
    np.testing.assert_allclose(ekf.measure(x), by_hand(x), rtol=1e-13)
    fd = np.empty((8, 12))
    for k in range(12):
        e = np.zeros(12)
        e[k] = 1e-7
        fd[:, k] = (by_hand(x + e) - by_hand(x - e)) / 2e-7
    np.testing.assert_allclose(h_mat, fd, rtol=1e-6, atol=1e-12)
    assert ekf.prior_in_front


def test_an_update_on_the_points_seen_is_the_reduced_filter_exactly():
    """A frame with points not found (NaN rows): the estimator's step is eqs. 3-5 then eq. 7
    written out with only the seen points' rows of h, H and R (numpy's inverse), for every subset
    of 1-3 points, to rounding; the prediction is kept for the rest, and with every point seen it
    is the usual update. The NIS its divergence rule counts has the seen rows only too."""
    rng = np.random.default_rng(3)
    model = camera_model()
    f = model.focal_length
    truth = np.array([0.02, 0.02, 1.2, -0.01, -0.01, 0.005, 0.4, 0.05, -0.3, -0.03, 0.6, 0.04])
    z_all = measurement(truth, FEATURES, f) + rng.normal(scale=PITCH, size=8)
    x0 = np.zeros(12)
    x0[POSE_INDEX] = [0.0, 1.19, 0.0, 0.38, -0.28, 0.62]
    x0[1::2] = [0.01, -0.02, 0.0, 0.03, 0.02, -0.01]
    p0 = default_initial_covariance()
    sigma = 0.01
    a = state_transition(DT)
    x = a @ x0  # the prior, eqs. 3-5
    p = a @ p0 @ a.T + process_noise(DT, (sigma**2,) * 6)
    r_all = measurement_sigma(1.0, model.pixel_pitch, NOISE_FLOOR_PX) ** 2 * np.eye(8)
    subsets = [[0], [2], [1, 3], [0, 1, 2], [1, 2, 3], [0, 1, 2, 3]]
    for seen in subsets:
        est = one_row(model, noise_px=1.0, sigma_acceleration=sigma)
        start = FilterRows(
            x0[BLOCK_ORDER][None],
            p0[np.ix_(BLOCK_ORDER, BLOCK_ORDER)][None],
            np.ones(1, dtype=bool),
            np.zeros(1, dtype=bool),
            np.zeros(1, dtype=np.int64),
            np.zeros(1, dtype=np.int64),
            np.zeros(1, dtype=np.int8),
            np.zeros(1),
        )
        est.restore([0], start)
        rows = np.ravel([[2 * i, 2 * i + 1] for i in seen])
        h = measurement(x, FEATURES, f)[rows]
        big_h = measurement_jacobian(x, FEATURES, f)[rows]
        r = r_all[np.ix_(rows, rows)]
        s = big_h @ p @ big_h.T + r
        k = p @ big_h.T @ np.linalg.inv(s)
        y = z_all[rows] - h
        i_kh = np.eye(12) - k @ big_h
        image = np.full((4, 2), np.nan)
        image[seen] = z_all.reshape(4, 2)[seen]
        x_block, p_block = x[BLOCK_ORDER][None], p[np.ix_(BLOCK_ORDER, BLOCK_ORDER)][None]
        nis = est._update(x_block, p_block.copy(), images_of(image))[3]
        assert est.update(images_of(image), dts()).status_names() == ["ok"]
        np.testing.assert_allclose(est.state[0], x + k @ y, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(
            est.covariance[0], i_kh @ p @ i_kh.T + k @ r @ k.T, rtol=1e-7, atol=1e-15
        )
        assert nis[0] == pytest.approx(y @ np.linalg.solve(s, y), rel=1e-7)


class Row(NamedTuple):
    """Row 0 of an `Estimates`: one episode's estimate."""

    position: np.ndarray
    velocity: np.ndarray
    covariance: np.ndarray
    valid: bool
    status: str


def step(
    est: TargetEstimator,
    frame: Frame | np.ndarray | None,
    dt: float = DT,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
) -> Row:
    """One update of a one-row estimator with ``frame`` (None: no frame)."""
    pv = None if truth is None else (truth[0][None], truth[1][None])
    out = est.update(images_of(frame), dts(dt), None, pv)
    return Row(
        out.position[0],
        out.velocity[0],
        out.covariance[0],
        bool(out.valid[0]),
        out.status_names()[0],
    )


def test_a_frame_missing_a_point_updates_but_never_initialises():
    model = camera_model()
    estimator = one_row(model, source="ekf", noise_px=1.0)
    position = np.array([0.4, 0.1, 0.4])
    image = model.project(model.to_camera(markers(position)))
    partial = image.copy()
    partial[2] = np.nan
    assert step(estimator, partial).status == "initialising"
    assert step(estimator, image).status == "ok"
    before = estimator.x.copy()
    assert step(estimator, partial).status == "ok"
    assert not np.array_equal(estimator.x, before)
    predicting = one_row(model, source="ekf", partial_frames="predict")
    step(predicting, image)
    assert step(predicting, partial).status == "predicting"
    with pytest.raises(ValueError, match="partial_frames"):
        one_row(model, partial_frames="guess")


def test_ekf_converges_on_drifting_tumbling_target():
    """Constant velocity and Euler rates in the camera frame (the model exactly), 1 px noise;
    the filter's own state (camera frame, block order) read after each step."""
    p0, v = np.array([0.02, 1.2, -0.01]), np.array([0.02, -0.01, 0.005])
    a0, w = np.array([0.4, -0.3, 0.6]), np.array([0.05, -0.03, 0.04])
    model = camera_model()
    f = model.focal_length
    early, late, vel_late, inside = [], [], [], []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        est = one_row(model, noise_px=1.0)
        errs = []
        for k in range(300):
            pose = np.concatenate([p0 + v * k * DT, a0 + w * k * DT])
            z = pose_projection(pose, FEATURES, f)[0].reshape(4, 2)
            z = z + rng.normal(scale=PITCH, size=(4, 2))
            assert step(est, z).status == "ok"  # the first initialises (photogrammetry)
            err = est.x[0, :3] - pose[:3]
            sd = np.sqrt(np.diag(est.P[0])[:3])
            errs.append(np.linalg.norm(err))
            if k >= 150:
                inside.append(np.all(np.abs(err) < 3 * sd))
                vel_late.append(np.linalg.norm(est.x[0, 6:9] - v))
        early += errs[:10]
        late += errs[-50:]
    assert np.mean(late) < 0.5 * np.mean(early)
    assert np.mean(vel_late) < 0.005  # m/s, against a 0.023 m/s drift
    assert np.mean(inside) >= 0.9


def test_estimator_tracks_circular_target_in_global_frame():
    """Camera ~1.2 m away, 1 px noise, target on a 5 cm circle at 0.3 rad/s."""
    cam = camera_model()
    centre, radius, omega = np.array([0.45, 0.0, 0.4]), 0.05, 0.3
    early, late, inside, vel_late = [], [], [], []
    for seed in range(3):
        rng = np.random.default_rng(100 + seed)
        sensor = Camera(cam, noise_px=1.0)
        state = sensor.reset()
        est = one_row(cam, source="ekf", noise_px=1.0)
        errs = []
        for k in range(300):
            t = k * DT
            pos = centre + radius * np.array([np.cos(omega * t), 0.0, np.sin(omega * t)])
            vel = radius * omega * np.array([-np.sin(omega * t), 0.0, np.cos(omega * t)])
            out = step(est, sensor.capture(state, markers(pos), rng))
            assert out.valid and out.status == "ok"
            err = out.position - pos
            errs.append(np.linalg.norm(err))
            if k >= 150:
                sd = np.sqrt(np.diag(out.covariance)[:3])
                inside.append(np.all(np.abs(err) < 3 * sd))
                vel_late.append(np.linalg.norm(out.velocity - vel))
        early += errs[:10]
        late += errs[-50:]
    assert np.mean(late) < 0.5 * np.mean(early)
    assert np.mean(vel_late) < 0.005
    assert np.mean(inside) >= 0.9


def test_truth_source_returns_truth():
    est = one_row(camera_model(), source="truth")
    p, v = np.array([0.4, 0.1, 0.3]), np.array([0.01, -0.02, 0.0])
    out = step(est, None, truth=(p, v))
    np.testing.assert_array_equal(out.position, p)
    np.testing.assert_array_equal(out.velocity, v)
    assert out.valid and out.status == "ok" and np.isnan(out.covariance).all()
    with pytest.raises(ValueError, match="truth"):
        step(est, None)


def test_bad_source_names_the_valid_ones():
    with pytest.raises(ValueError, match="'ekf', 'photogrammetry', 'truth'"):
        one_row(camera_model(), source="kalman")


def _noiseless_run(source: str, latency: int = 0, lose: tuple[int, ...] = ()):
    """A target drifting at (0.02, 0.01, -0.01) m/s seen by a noise-free camera."""
    cam = camera_model()
    sensor = Camera(cam, noise_px=0.0, latency_frames=latency)
    state = sensor.reset()
    est = one_row(cam, source=source, noise_px=0.0)
    rng = np.random.default_rng(0)
    p0, v = np.array([0.45, 0.0, 0.4]), np.array([0.02, 0.01, -0.01])
    outs, truth = [], []
    for k in range(12):
        pos = p0 + v * k * DT
        frame = sensor.capture(state, markers(pos), rng)
        outs.append(step(est, None if k in lose else frame, truth=(pos, v)))
        truth.append(pos)
    return outs, np.array(truth), v


def test_lost_frames_keep_predicting():
    outs, truth, v = _noiseless_run("ekf", lose=(6, 7, 8))
    assert [o.status for o in outs[5:10]] == ["ok", "predicting", "predicting", "predicting", "ok"]
    assert all(o.valid for o in outs)
    # Predict-only steps move the estimate by its velocity and grow its covariance.
    np.testing.assert_allclose(outs[7].position, outs[6].position + DT * outs[6].velocity)
    assert (
        np.trace(outs[8].covariance) > np.trace(outs[6].covariance) > np.trace(outs[5].covariance)
    )
    assert np.linalg.norm(outs[-1].position - truth[-1]) < 1e-3


def test_latency_delivers_frames_late():
    outs, truth, _ = _noiseless_run("photogrammetry", latency=3)
    assert [o.status for o in outs[:4]] == ["initialising"] * 3 + ["ok"]
    assert not outs[0].valid and np.all(np.isnan(outs[0].position))
    for k in range(3, 12):  # the estimate is the target as it was three steps before
        np.testing.assert_allclose(outs[k].position, truth[k - 3], atol=1e-9)
    outs, _, _ = _noiseless_run("ekf", latency=3)
    assert [o.status for o in outs[:4]] == ["initialising"] * 3 + ["ok"]


def test_photogrammetry_velocity_by_finite_difference():
    outs, truth, v = _noiseless_run("photogrammetry", lose=(5,))
    np.testing.assert_allclose(outs[0].velocity, 0.0)
    np.testing.assert_allclose(outs[3].velocity, v, atol=1e-7)
    assert outs[5].status == "predicting"
    np.testing.assert_allclose(outs[5].position, outs[4].position)
    np.testing.assert_allclose(outs[6].velocity, v, atol=1e-7)  # elapsed time 2 dt
    assert np.isnan(outs[6].covariance).all()


def test_divergence_reinitialises_from_photogrammetry():
    cam = camera_model()
    sensor = Camera(cam, noise_px=1.0)
    state = sensor.reset()
    est = one_row(cam, source="ekf", noise_px=1.0)
    rng = np.random.default_rng(4)
    pos, jump = np.array([0.45, 0.0, 0.4]), np.array([0.0, -0.3, 0.05])
    for _ in range(20):
        step(est, sensor.capture(state, markers(pos), rng))
    # The target jumps 30 cm: the filter, confident in a still target, rejects the frames until
    # the NIS rule trips, then photogrammetry restarts it near the new position.
    outs = [step(est, sensor.capture(state, markers(pos + jump), rng))]
    for _ in range(DIVERGENCE_FRAMES + 1):
        outs.append(step(est, sensor.capture(state, markers(pos + jump), rng)))
    assert est.reinitialisations[0] == 1
    assert est.high_nis[0] == 0  # the last update's NIS under the limit
    assert np.linalg.norm(outs[-1].position - (pos + jump)) < 0.01
    # A non-finite filter is diverged; without a frame it cannot restart and says so.
    est.P[0, 0, 0] = np.nan
    out = step(est, None)
    assert out.status == "diverged" and not out.valid
    out = step(est, cam.project(cam.to_camera(markers(pos))))
    assert out.status == "ok" and np.linalg.norm(out.position - pos) < 0.01
    assert est.reinitialisations[0] == 2
    # A prediction that puts the target behind the lens (absurd velocity toward the camera).
    est.x[0, BLOCK_ORDER.tolist().index(3)] = -40.0  # y_dot in the camera frame, m/s
    out = step(est, cam.project(cam.to_camera(markers(pos))))
    assert out.status == "ok" and est.reinitialisations[0] == 3
    assert np.linalg.norm(out.position - pos) < 0.01
