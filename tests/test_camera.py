"""Camera geometry (eq. 2), visibility, noise, drop-out and latency."""

from __future__ import annotations

import numpy as np
import pytest

from capture_bench.sensing.camera import Camera, CameraModel

FEATURES = np.array([(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.05)], dtype=float)


def side_camera() -> CameraModel:
    """Camera at global (1, 0, 0) looking at the origin.

    By hand (look_at with up = z): y_c = (-1, 0, 0), x_c = y_c x z = (0, 1, 0), z_c = (0, 0, 1).
    """
    return CameraModel.looking_at((1.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def test_looking_at_axes_by_hand():
    cam = side_camera()
    np.testing.assert_allclose(cam.rotation, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)


def test_projection_hand_computed_in_camera_frame():
    cam = CameraModel(np.zeros(3), np.eye(3))
    # (x_C, y_C, z_C) = (0.02, 0.408, -0.01): y_C - f = 0.4,
    # x_m = -0.008 * 0.02 / 0.4 = -0.0004, z_m = -0.008 * -0.01 / 0.4 = +0.0002.
    np.testing.assert_allclose(cam.project([[0.02, 0.408, -0.01]]), [[-0.0004, 0.0002]], rtol=1e-12)


def test_projection_hand_computed_through_global_frame():
    cam = side_camera()
    # Global (0, 0.05, 0.02) - camera (1, 0, 0) = (-1, 0.05, 0.02);
    # x_C = (0, 1, 0).(-1, 0.05, 0.02) = 0.05, y_C = (-1, 0, 0).(...) = 1, z_C = 0.02.
    p_cam = cam.to_camera([[0.0, 0.05, 0.02]])
    np.testing.assert_allclose(p_cam, [[0.05, 1.0, 0.02]], atol=1e-15)
    # y_C - f = 0.992: x_m = -0.0004 / 0.992 = -4.032258064516129e-4,
    # z_m = -0.00016 / 0.992 = -1.6129032258064516e-4.
    np.testing.assert_allclose(
        cam.project(p_cam), [[-4.032258064516129e-4, -1.6129032258064516e-4]], rtol=1e-12
    )


def test_half_fov_by_hand():
    # half width 640 * 3.75e-6 = 2.4 mm, half height 480 * 3.75e-6 = 1.8 mm, f = 8 mm.
    h, v = CameraModel(np.zeros(3), np.eye(3)).half_fov
    assert h == pytest.approx(np.arctan(0.3))
    assert v == pytest.approx(np.arctan(0.225))


def test_round_trip_global_camera():
    rng = np.random.default_rng(3)
    cam = CameraModel.looking_at((0.4, -1.2, 0.6), (0.45, 0.0, 0.3))
    pts = rng.uniform(-1, 1, size=(10, 3))
    np.testing.assert_allclose(cam.to_global(cam.to_camera(pts)), pts, atol=1e-14)
    np.testing.assert_allclose(cam.to_camera(cam.to_global(pts)), pts, atol=1e-14)
    v = rng.normal(size=(5, 3))
    np.testing.assert_allclose(
        cam.vector_to_global(v), cam.to_global(v) - cam.to_global(np.zeros((5, 3))), atol=1e-14
    )


def test_in_front_and_on_sensor():
    cam = CameraModel(np.zeros(3), np.eye(3))
    pts = np.array(
        [
            [0.0, 1.0, 0.0],  # on axis, in front
            [0.0, 0.005, 0.0],  # between image plane and lens (f = 0.008): behind the lens
            [0.0, -1.0, 0.0],  # behind the camera
            [1.0, 1.0, 0.0],  # x_m = -0.008 / 0.992 ~ -8 mm, beyond the 2.4 mm half width
            [0.0, 1.0, 0.2],  # z_m ~ -1.61 mm, inside the 1.8 mm half height
            [0.0, 1.0, 0.25],  # z_m ~ -2.02 mm, outside
        ]
    )
    np.testing.assert_array_equal(cam.in_front(pts), [True, False, False, True, True, True])
    np.testing.assert_array_equal(cam.visible(pts), [True, False, False, False, True, False])


@pytest.mark.parametrize(
    "offset",
    [(0.0, -1.3, 0.0), (0.0, 0.0, 1.0)],
    ids=["behind_lens", "off_sensor"],
)
def test_unseen_point_gives_no_frame(offset):
    cam = CameraModel.looking_at((0.0, -1.2, 0.0), (0.0, 0.0, 0.0))
    sensor = Camera(cam, noise_px=1.0)
    state = sensor.reset()
    pts = FEATURES.copy()
    pts[2] += offset  # one point leaves the view
    assert sensor.capture(state, pts, np.random.default_rng(0)) is None
    assert state.last_visible is False
    assert state.last_dropped is False
    assert sensor.capture(state, FEATURES, np.random.default_rng(0)) is not None
    assert state.last_visible is True


def test_noise_statistics_and_determinism():
    cam = CameraModel.looking_at((0.0, -1.2, 0.0), (0.0, 0.0, 0.0))
    exact = cam.project(cam.to_camera(FEATURES))
    sensor = Camera(cam, noise_px=1.0)
    state, rng = sensor.reset(), np.random.default_rng(7)
    errs = np.array(
        [sensor.capture(state, FEATURES, rng).image_points - exact for _ in range(2000)]
    )
    assert np.std(errs) / cam.pixel_pitch == pytest.approx(1.0, rel=0.05)
    assert abs(np.mean(errs)) / cam.pixel_pitch < 0.05
    noisy = Camera(cam, noise_px=1.0, dropout=0.3)
    a = noisy.capture(noisy.reset(), FEATURES, np.random.default_rng(11))
    b = noisy.capture(noisy.reset(), FEATURES, np.random.default_rng(11))
    assert (a is None) == (b is None)
    if a is not None:
        np.testing.assert_array_equal(a.image_points, b.image_points)


def test_dropout_rate_and_flag():
    cam = CameraModel.looking_at((0.0, -1.2, 0.0), (0.0, 0.0, 0.0))
    sensor = Camera(cam, dropout=0.4)
    state, rng = sensor.reset(), np.random.default_rng(1)
    frames = [sensor.capture(state, FEATURES, rng) for _ in range(1000)]
    lost = sum(f is None for f in frames)
    assert 340 < lost < 460
    state = sensor.reset()
    while sensor.capture(state, FEATURES, rng) is not None:
        pass
    assert state.last_dropped and state.last_visible


def test_latency_delivers_frames_late():
    cam = CameraModel.looking_at((0.0, -1.2, 0.0), (0.0, 0.0, 0.0))
    sensor = Camera(cam, noise_px=0.0, latency_frames=2)
    state, rng = sensor.reset(), np.random.default_rng(0)
    shifts = [np.array([0.01 * k, 0.0, 0.0]) for k in range(5)]
    out = [sensor.capture(state, FEATURES + s, rng) for s in shifts]
    assert out[0] is None and out[1] is None
    for k in range(2, 5):
        expected = cam.project(cam.to_camera(FEATURES + shifts[k - 2]))
        np.testing.assert_allclose(out[k].image_points, expected, atol=1e-15)
        assert out[k].capture_index == k - 2
    assert sensor.capture(sensor.reset(), FEATURES, rng) is None  # a new episode's pipeline


def test_episodes_interleaved_on_one_camera_see_what_each_sees_alone():
    """An episode's pipeline, count and flags are its `CameraEpisode`: two episodes captured in
    turn on one camera get, call by call, the frames and flags each gets alone, and
    capture_sequence is a new episode's captures."""
    cam = CameraModel.looking_at((0.0, -1.2, 0.0), (0.0, 0.0, 0.0))
    sensor = Camera(cam, noise_px=1.0, dropout=0.3, latency_frames=2)
    paths = [
        [FEATURES + np.array([0.02 * k * sign, 0.0, 0.0]) for k in range(30)] for sign in (1, -1)
    ]

    def seen(state, frame):
        points = None if frame is None else (frame.image_points.tolist(), frame.capture_index)
        return points, state.last_visible, state.last_dropped

    alone = []
    for j, path in enumerate(paths):
        state, rng = sensor.reset(), np.random.default_rng(j)
        alone.append([seen(state, sensor.capture(state, p, rng)) for p in path])
        images, visible = Camera(cam, 1.0, 0.3, 2).capture_sequence(
            np.stack(path), np.random.default_rng(j)
        )
        delivered = [None if np.isnan(i).all() else i.tolist() for i in images]
        assert delivered == [s[0] and s[0][0] for s in alone[j]]
        assert visible.tolist() == [s[1] for s in alone[j]]
    states = [sensor.reset(), sensor.reset()]
    rngs = [np.random.default_rng(0), np.random.default_rng(1)]
    together = [[], []]
    for k in range(30):
        for j in (1, 0):
            frame = sensor.capture(states[j], paths[j][k], rngs[j])
            together[j].append(seen(states[j], frame))
    assert together == alone
    assert any(s[0] is None for s in alone[0][2:]) and any(s[0] for s in alone[0])


def test_bad_arguments_raise():
    cam = CameraModel(np.zeros(3), np.eye(3))
    with pytest.raises(ValueError, match="dropout"):
        Camera(cam, dropout=1.0)
    with pytest.raises(ValueError, match="latency"):
        Camera(cam, latency_frames=-1)
    with pytest.raises(ValueError, match="orthonormal"):
        CameraModel(np.zeros(3), 2 * np.eye(3))
