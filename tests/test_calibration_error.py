"""Lens distortion and the per-episode calibration error of the rendered camera: the draw is the
episode seed's, keys at 0 change nothing, the distortion's inverse is exact and OpenCV's, the
estimator reads the frames with the nominal calibration, bad keys are refused in one line, and
the point-level distortion of a centroid stands for distorting the image."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.sensing.calibration import CalibrationSpread, Distortion, TrueCamera
from capture_bench.sensing.camera import Camera
from capture_bench.sensing.detector import MARKER_BANDS, detect_markers
from capture_bench.sensing.pixels import (
    pixel_of,
    pixel_to_global,
    pixel_to_image_plane,
    principal_point,
    sphere_image,
)
from capture_bench.sensing.rendered_sensor import RenderedCamera, RenderSettings, marker_windows
from capture_bench.sensing.scene_camera import RenderedSceneCamera
from capture_bench.sim.target_motion import FEATURE_POINTS, random_rotation
from capture_bench.task.scenarios import CameraConfig, ConfigError, load_scenario

FEATURES = FEATURE_POINTS["non_coplanar"]
MODEL = CameraConfig().model()
PITCH = MODEL.pixel_pitch
SCALE = MODEL.focal_length / PITCH  # F = f / pitch, pixels
AWAY = lambda t: np.array([np.pi, np.pi / 2, 0.0])  # noqa: E731  the arm out of view
#: An error larger than the shipped one on every key, so that each shows.
SPREAD = CalibrationSpread(
    Distortion(-0.2, 0.05, 0.001, -0.0005),
    focal=0.005,
    principal=3.0,
    k1=0.02,
    rotation=math.radians(0.1),
    position=0.001,
)
KEYS = {
    "distortion_k1": -0.2,
    "calibration_focal": 0.005,
    "calibration_principal_px": 3.0,
    "calibration_k1": 0.02,
    "calibration_rotation_deg": 0.1,
    "calibration_position": 0.001,
}
LENSES = [
    Distortion(-0.3, 0.0, 0.0, 0.0),
    Distortion(0.3, -0.2, 0.002, -0.003),
    Distortion(-0.18, 0.12, -0.001, 0.0007),
]


def _scenes(count: int, seed: int):
    """``pose_at`` of still targets 0.9-1.4 m beyond the lens, every marker well inside view."""
    rng = np.random.default_rng(seed)
    scenes = []
    while len(scenes) < count:
        pixel = rng.uniform([250, 200], [1030, 760])
        position = pixel_to_global(pixel[None], rng.uniform(0.9, 1.4, 1), MODEL)[0]
        rotation = random_rotation(rng)
        points = position + FEATURES @ rotation.T
        if MODEL.visible(MODEL.to_camera(points), margin=0.1).all():
            scenes.append(lambda t, p=position, r=rotation: (p, r))
    return scenes


def _true_camera_fields(lens: TrueCamera) -> list[np.ndarray]:
    d = lens.distortion
    return [
        lens.model.position,
        lens.model.rotation,
        np.array([lens.model.focal_length, d.k1, d.k2, d.p1, d.p2]),
        lens.principal_offset,
    ]


# -- the draw ------------------------------------------------------------------------------------
def test_the_error_is_the_episode_seeds_and_draws_nothing_from_its_generator():
    same = [SPREAD.draw(12345, MODEL), SPREAD.draw(12345, MODEL)]
    other = SPREAD.draw(12346, MODEL)
    for a, b, c in zip(*map(_true_camera_fields, (*same, other)), strict=True):
        np.testing.assert_array_equal(a, b)
        assert not np.array_equal(a, c)
    with RenderedCamera(MODEL, FEATURES, calibration=SPREAD) as camera:
        rng = np.random.default_rng(7)
        episode = camera.reset(rng)
        check = np.random.default_rng(7)
        assert episode.noise_key == int(check.integers(0, 2**64, dtype=np.uint64))
        assert rng.bit_generator.state == check.bit_generator.state  # the key's one draw only
        assert episode.lens is not None
        again = camera.reset(np.random.default_rng(7)).lens
        for a, b in zip(_true_camera_fields(episode.lens), _true_camera_fields(again)):
            np.testing.assert_array_equal(a, b)
    lens = same[0]  # the error is the spread's size, the nominal values stay
    assert abs(lens.model.focal_length / MODEL.focal_length - 1.0) < 5 * SPREAD.focal
    assert 0.0 < np.linalg.norm(lens.model.position - MODEL.position) < 0.01
    assert lens.distortion.k2 == SPREAD.distortion.k2 and lens.distortion.k1 != -0.2


def test_an_env_episode_has_the_error_of_its_seed():
    sc = load_scenario("paper_rendered").replace(camera=KEYS)
    env = CaptureEnv(sc)
    try:
        lenses = []
        for seed in (3, 4, 3):
            env.reset(seed=seed)
            episode = env.engine.sides.sides[0].camera_episode
            lenses.append(_true_camera_fields(episode.lens))
    finally:
        env.close()
    for a, b, c in zip(*lenses, strict=True):
        np.testing.assert_array_equal(a, c)
        assert not np.array_equal(a, b)


def test_the_camera_view_draws_the_detections_on_the_true_pinholes_image():
    """``render_view="camera"``: the image of the episode's true pinhole, with the detector's
    centroids in it (before the lens), where the markers are."""
    env = CaptureEnv("paper_rendered", render_mode="rgb_array", render_size=(320, 240))
    try:
        env.reset(seed=3)
        image = env.render()
        side = env.engine.sides.sides[0]
        state = side.camera_episode
        true = env.engine.sides.camera.true_model(state)
        assert true is state.lens.model and image.shape == (240, 320, 3)
        ep = side.episode
        centres = ep.position[0] + env.task.features @ ep.rotation[0].T
        expected = pixel_of(true.to_camera(centres), true)
        found = state.last_detections.found
        assert found.any()
        error = np.abs(state.last_detections.pixels[found] - expected[found])
        assert error.max() < 0.3, error
    finally:
        env.close()


# -- keys at 0 -----------------------------------------------------------------------------------
def test_every_key_at_zero_gives_the_frames_of_before():
    assert not CameraConfig().calibration_spread().active
    sc = load_scenario("paper_rendered").replace(
        camera=dict.fromkeys([*KEYS, "distortion_k2", "distortion_p1", "distortion_p2"], 0.0)
    )
    with RenderedSceneCamera.for_scenario(sc) as zero:
        assert zero.calibration is None
    settings = RenderSettings(image_noise=4.0)
    with (
        RenderedCamera(MODEL, FEATURES, settings, dropout=0.3) as before,
        RenderedCamera(MODEL, FEATURES, settings, 0.3, 0, CalibrationSpread()) as keys_zero,
    ):
        a, b = before.reset(np.random.default_rng(2)), keys_zero.reset(np.random.default_rng(2))
        assert b.lens is None
        for k, pose_at in enumerate(_scenes(3, seed=1)):
            fa = before.capture(a, pose_at, 0.0, AWAY, np.random.default_rng(k), k)
            fb = keys_zero.capture(b, pose_at, 0.0, AWAY, np.random.default_rng(k), k)
            assert (fa is None) == (fb is None)
            if fa is not None:
                np.testing.assert_array_equal(fa.image_points, fb.image_points)
                np.testing.assert_array_equal(fa.status, fb.status)


# -- the distortion ------------------------------------------------------------------------------
@pytest.mark.parametrize("lens", LENSES)
def test_distortion_round_trip_is_the_identity(lens):
    """Distort with the nominal coefficients, undistort with them: the same image-plane point to
    1e-9 pixel (1e-9 of the pitch, metres), over the sensor and beyond its corners."""
    rng = np.random.default_rng(0)
    corner = float(np.hypot(*MODEL.half_extent)) / MODEL.focal_length
    n = rng.uniform(-1.2 * corner, 1.2 * corner, (2000, 2))
    distorted = lens.apply(n)
    np.testing.assert_allclose(lens.remove(distorted), n, rtol=0, atol=1e-12)
    one_by_one = np.vstack([lens.remove(distorted[i : i + 4]) for i in range(0, 40, 4)])
    np.testing.assert_allclose(one_by_one, lens.remove(distorted)[:40], rtol=0, atol=1e-15)
    camera = TrueCamera(MODEL, np.zeros(2), lens, MODEL, lens)
    pixels = rng.uniform([-0.5, -0.5], [1279.5, 959.5], (2000, 2))
    back = camera.calibrated_points(camera.measured_pixels(pixels))
    np.testing.assert_allclose(back, pixel_to_image_plane(pixels, MODEL), rtol=0, atol=1e-9 * PITCH)


@pytest.mark.parametrize("lens", LENSES)
def test_distortion_is_opencvs(lens):
    """``cv2.projectPoints`` of camera-frame points (OpenCV's axes: x_C, -z_C, y_C - f) with
    the same coefficients gives `TrueCamera.measured_pixels` of their pinhole pixels, and
    ``cv2.undistortPoints`` run to convergence gives `Distortion.remove`."""
    rng = np.random.default_rng(1)
    pixels = rng.uniform(0, [1279, 959], (200, 2))
    points = MODEL.to_camera(pixel_to_global(pixels, np.full(200, 1.2), MODEL))
    k = np.array([[SCALE, 0.0, 639.5], [0.0, SCALE, 479.5], [0.0, 0.0, 1.0]])
    coefficients = np.array([lens.k1, lens.k2, lens.p1, lens.p2])
    opencv = np.column_stack([points[:, 0], -points[:, 2], points[:, 1] - MODEL.focal_length])
    projected, _ = cv2.projectPoints(opencv, np.zeros(3), np.zeros(3), k, coefficients)
    camera = TrueCamera(MODEL, np.zeros(2), lens, MODEL, lens)
    ours = camera.measured_pixels(pixel_of(points, MODEL))
    np.testing.assert_allclose(projected[:, 0], ours, rtol=0, atol=1e-6)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 1000, 1e-12)
    undistorted = cv2.undistortPoints(
        ours[:, None], k, coefficients, None, np.eye(3), np.eye(3), criteria
    )
    centre = principal_point(MODEL)
    expected = lens.remove((ours - centre) / SCALE)
    np.testing.assert_allclose(undistorted[:, 0], expected, rtol=0, atol=1e-9)


# -- the estimator's calibration -----------------------------------------------------------------
def test_the_estimator_reads_the_perturbed_cameras_frames_with_the_nominal_calibration():
    sc = load_scenario("paper_rendered").replace(camera=KEYS)
    nominal = sc.camera.model()
    env = CaptureEnv(sc)
    try:
        env.reset(seed=11)
        sides = env.engine.sides
        side = sides.sides[0]
        estimator_model = sides.estimators[0].camera_model
        lens = side.camera_episode.lens
    finally:
        env.close()
    for name in ("position", "rotation", "focal_length", "pixel_pitch"):
        np.testing.assert_array_equal(getattr(estimator_model, name), getattr(nominal, name))
        np.testing.assert_array_equal(getattr(lens.nominal, name), getattr(nominal, name))
    assert lens.model.focal_length != nominal.focal_length
    assert not np.array_equal(lens.model.rotation, nominal.rotation)
    known = sc.camera.calibration_spread().distortion
    assert lens.nominal_distortion == known != lens.distortion and known.k1 == -0.2
    # A frame of the true camera, read with the nominal calibration
    with RenderedCamera(MODEL, FEATURES, calibration=SPREAD) as camera:
        episode = camera.reset(np.random.default_rng(4))
        true = episode.lens
        for k, pose_at in enumerate(_scenes(4, seed=2)):
            frame = camera.capture(episode, pose_at, 0.0, AWAY, np.random.default_rng(k), k)
            position, rotation = pose_at(0.0)
            centres = position + FEATURES @ rotation.T
            seen = true.measured_pixels(pixel_of(true.model.to_camera(centres), true.model))
            expected = true.calibrated_points(seen)
            error = np.abs(frame.image_points - expected) / PITCH
            assert frame.found.all() and error.max() < 0.3, error  # the detector's error
            nominal_eq2 = MODEL.project(MODEL.to_camera(centres))
            assert np.abs(frame.image_points - nominal_eq2).max() / PITCH > 1.0


# -- validation ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("key", "value", "valid"),
    [
        ("distortion_k1", "-1.5", "in [-1, 1]"),
        ("distortion_p2", "0.5", "in [-0.1, 0.1]"),
        ("calibration_focal", "0.2", "in [0, 0.1]"),
        ("calibration_principal_px", "-1", "in [0, 50]"),
        ("calibration_rotation_deg", "10", "in [0, 5]"),
        ("calibration_position", "1.0e300", "in [0, 0.05]"),
    ],
)
def test_a_key_out_of_range_is_one_line_naming_it(tmp_path: Path, key, value, valid):
    path = tmp_path / "lens.yaml"
    path.write_text(f"camera:\n  mode: rendered\n  {key}: {value}\n")
    with pytest.raises(ConfigError) as raised:
        load_scenario(path)
    message = str(raised.value)
    assert message.startswith(f"{path}: key 'camera.{key}': ") and "\n" not in message
    assert valid in message, message


# -- the analytic camera ---------------------------------------------------------------------
def test_the_analytic_camera_projects_through_the_true_camera():
    """All keys 0: the frames of before, bit for bit, and reset draws nothing. With an error:
    reset draws the key (one integer) and the lens from it; `capture_sequence` (the recorded
    path) gives `capture`'s frames (the live path) bit for bit; a frame is the nominal reading of
    the true camera's noisy pixels."""
    scenes = [pose_at(0.0) for pose_at in _scenes(6, seed=3)]
    points = np.stack([p + FEATURES @ r.T for p, r in scenes])
    plain = Camera(MODEL, noise_px=0.5, dropout=0.2, latency_frames=1)
    zero = Camera(MODEL, 0.5, 0.2, 1, CalibrationSpread())
    lensed = Camera(MODEL, 0.5, 0.2, 1, SPREAD)
    expected = plain.capture_sequence(points, np.random.default_rng(5))
    rng = np.random.default_rng(5)
    state = zero.reset(rng)
    assert (
        state.lens is None
        and rng.bit_generator.state == np.random.default_rng(5).bit_generator.state
    )
    for a, b in zip(zero.capture_sequence(points, np.random.default_rng(5)), expected):
        np.testing.assert_array_equal(a, b)
    rng = np.random.default_rng(5)
    state = lensed.reset(rng)
    key = int(np.random.default_rng(5).integers(0, 2**64, dtype=np.uint64))
    for a, b in zip(_true_camera_fields(state.lens), _true_camera_fields(SPREAD.draw(key, MODEL))):
        np.testing.assert_array_equal(a, b)
    live = [lensed.capture(state, p, rng) for p in points]
    images, visible = lensed.capture_sequence(points, np.random.default_rng(5))
    assert visible.all()
    for k, frame in enumerate(live):
        if frame is None:
            assert np.isnan(images[k]).all()
        else:
            np.testing.assert_array_equal(frame.image_points, images[k])
    true = state.lens
    nominal_eq2 = MODEL.project(MODEL.to_camera(points[0]))
    seen = true.calibrated_points(
        true.measured_pixels(pixel_of(true.model.to_camera(points[0]), true.model))
    )
    assert np.abs(images[1] - seen).max() / PITCH < 3.0  # the frame taken at 0, 0.5 px of noise
    assert np.abs(images[1] - nominal_eq2).max() / PITCH > 3.0


def test_an_analytic_episode_live_is_its_recording():
    sc = load_scenario("paper").replace(camera=KEYS)
    live, recorded = CaptureEnv(sc), CaptureEnv(sc, reuse_target_side=True)
    try:
        for env in (live, recorded):
            env.reset(seed=7)
        lens = live.engine.sides.sides[0].camera_episode.lens
        assert lens is not None
        action = np.zeros(3)
        for _ in range(15):
            a, b = live.step(action), recorded.step(action)
            np.testing.assert_array_equal(a[0], b[0])
            assert a[4]["estimate_position_error"] == b[4]["estimate_position_error"]
    finally:
        live.close()
        recorded.close()


# -- the point-level approximation ---------------------------------------------------------------
def _inside_sphere_image(centre_cam: np.ndarray, radius: float, step: float) -> np.ndarray:
    """Pixels ``[u, v]`` of a grid of ``step`` px inside the exact (pinhole) image of a sphere."""
    image = sphere_image(centre_cam[None], radius, MODEL)
    reach = image.semi_major[0] + 1.0
    grid = np.arange(-reach, reach, step)
    u, v = np.meshgrid(grid + image.centre[0, 0], grid + image.centre[0, 1])
    pixels = np.column_stack([u.ravel(), v.ravel()])
    c = principal_point(MODEL)
    ray = np.column_stack([(pixels - c) / SCALE * [1.0, -1.0], np.ones(len(pixels))])
    d = centre_cam - np.array([0.0, MODEL.focal_length, 0.0])
    g = d[[0, 2, 1]]
    inside = (ray @ g) ** 2 - (d @ d - radius**2) * np.einsum("ni,ni->n", ray, ray) >= 0.0
    return pixels[inside]


@pytest.mark.parametrize("lens", LENSES[:2])
def test_distorting_the_centroid_stands_for_distorting_the_markers_image(lens):
    """At the sensor's corners, where distortion is largest: the centroid of the distorted exact
    image of a 5 mm marker 1.2 m away is the distorted centroid to 0.01 px (0.1 px for a 10 mm
    marker at 0.6 m, 38 px across), and a rendered 5 mm blob 1.2 m away near each corner warped by
    ``cv2.remap`` has its centroid within 0.2 px of the distorted one, no farther than the same
    blob warped by a plain sub-pixel shift to the same place (the resampling of a blob that the
    detector thresholds)."""
    camera = TrueCamera(MODEL, np.zeros(2), lens, MODEL, Distortion())
    c = principal_point(MODEL)
    for corner in ((0.0, 0.0), (1279.0, 959.0), (0.0, 959.0)):
        for depth, radius, step, bound in ((1.2, 0.005, 0.02, 0.01), (0.6, 0.01, 0.1, 0.1)):
            centre = pixel_to_global(np.array([corner]), np.array([depth]), MODEL)[0]
            pixels = _inside_sphere_image(MODEL.to_camera(centre[None])[0], radius, step)
            warped = camera.measured_pixels(pixels).mean(axis=0)
            pointwise = camera.measured_pixels(pixels.mean(axis=0)[None])[0]
            assert np.hypot(*(warped - pointwise)) < bound
    errors: dict[str, list[float]] = {"lens": [], "shift": []}
    with RenderedCamera(MODEL, FEATURES, RenderSettings(marker_radius=0.005)) as rendered:
        for corner in ((60.0, 40.0), (1220.0, 920.0), (50.0, 900.0), (1240.0, 50.0)):
            for warp in ("lens", "shift"):
                centre = pixel_to_global(np.array([corner]), np.array([1.2]), MODEL)[0]
                pose_at = lambda t, p=centre - FEATURES[0]: (p, np.eye(3))  # noqa: E731
                pinhole = rendered.detect(pose_at, 0.0, AWAY, 0).pixels[0]
                window = marker_windows(MODEL, MODEL.to_camera(centre[None])[None], 0.005)[0]
                source = rendered.image(pose_at, 0.0, AWAY, 0, window)
                expected = camera.measured_pixels(pinhole[None])[0]
                half = 0.5 * max(window[1] - window[0], window[3] - window[2]) + 4.0
                u0, v0 = (int(x) for x in np.floor(expected - half))
                u1, v1 = (int(x) for x in np.ceil(expected + half))
                u, v = np.meshgrid(np.arange(u0, u1, dtype=float), np.arange(v0, v1, dtype=float))
                target = np.column_stack([u.ravel(), v.ravel()])
                if warp == "lens":  # where each measured pixel's light comes from
                    origin = c + SCALE * lens.remove((target - c) / SCALE)
                else:
                    origin = target - (expected - pinhole)
                maps = [
                    (origin[:, i] - window[2 * i]).reshape(u.shape).astype(np.float32)
                    for i in (0, 1)
                ]
                image = cv2.remap(source, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                found = detect_markers(image, None, (u0, v0), [MARKER_BANDS[0]])
                assert found.found[0]
                errors[warp].append(float(np.hypot(*(found.pixels[0] - expected))))
    assert max(errors["lens"]) < 0.2 and max(errors["lens"]) <= max(errors["shift"]), errors


@pytest.mark.parametrize(
    ("key", "spread", "least_px"),
    [
        ("focal", {"focal": 0.005}, 0.3),
        ("principal", {"principal": 3.0}, 0.3),
        ("k1", {"distortion": Distortion(-0.2), "k1": 0.02}, 0.02),
        ("rotation", {"rotation": math.radians(0.1)}, 0.3),
        ("position", {"position": 0.001}, 0.3),
    ],
)
def test_each_calibration_key_alone_moves_the_frame_off_the_nominal_projection(
    key, spread, least_px
):
    """A noise-free analytic camera: with one key alone (its distortion known, its k1 error
    alone for ``k1``), the frames read with the nominal calibration lie off eq. 2 of the nominal
    camera by at least ``least_px`` on some marker; with that key at 0 they lie on it."""
    points = np.stack([p + FEATURES @ r.T for p, r in (s(0.0) for s in _scenes(3, seed=7))])
    known = spread.get("distortion", Distortion())
    for on in (True, False):
        chosen = spread if on else {"distortion": known}
        camera = Camera(MODEL, 0.0, 0.0, 0, CalibrationSpread(**chosen))
        images, visible = camera.capture_sequence(points, np.random.default_rng(9))
        assert visible.all()
        off = max(
            np.abs(images[k] - MODEL.project(MODEL.to_camera(points[k]))).max() / PITCH
            for k in range(len(points))
        )
        if on:
            assert off >= least_px, (key, off)
        else:
            assert off < 1e-6, (key, off)
