"""Tests of the rendered camera sensor: its frames against eq. 2, the windowed fast path against
the full frame, noise, blur, light, drop-out and latency against the analytic camera, and its use
of the caller's random stream.

Full frames cost ~60 ms each (TinyRenderer on the CPU): the scenes compared with them are few and
chosen to cover the hard cases (the arm in front of a marker, markers overlapping, at the sensor's
edge, across a power-of-two pixel coordinate).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from capture_bench.sensing import detector as det
from capture_bench.sensing.camera import Camera, CameraModel, Frame
from capture_bench.sensing.occlusion import hidden_markers
from capture_bench.sensing.pixels import pixel_of, pixel_to_global, sphere_image
from capture_bench.sensing.render_camera import Lighting, lens_position
from capture_bench.sensing.rendered_sensor import (
    RenderedCamera,
    RenderedFrame,
    RenderSettings,
    exact_origin,
    marker_windows,
    pixel_noise,
    window_keeps,
)
from capture_bench.sim import kinematics
from capture_bench.sim.markers import MARKER_RADIUS
from capture_bench.sim.target_motion import FEATURE_POINTS, random_rotation
from capture_bench.task.scenarios import CameraConfig

FEATURES = FEATURE_POINTS["non_coplanar"]
HOME = kinematics.HOME
ARM_AWAY = (np.pi, np.pi / 2, 0.0)  # rad: the arm points to -x, out of the camera's view


def default_camera() -> CameraModel:
    return CameraConfig().model()


MODEL = default_camera()
WIDTH, HEIGHT = MODEL.resolution


def placed(pixel, depth, rotation=None):
    """``pose_at`` of a still target whose capture point projects to ``pixel`` at ``depth`` m
    beyond the lens (rotation identity unless given)."""
    position = pixel_to_global(np.atleast_2d(pixel), np.array([depth]), MODEL)[0]
    rotation = np.eye(3) if rotation is None else rotation
    return lambda t: (position, rotation)


def at(theta):
    return lambda t: np.asarray(theta, dtype=float)


def markers(pose_at, t=0.0):
    position, rotation = pose_at(t)
    return position + FEATURES @ rotation.T


def true_pixels(pose_at, t=0.0):
    return pixel_of(MODEL.to_camera(markers(pose_at, t)), MODEL)


def random_scenes(count, seed, depths=(0.6, 2.0), clear=False):
    """``(pose_at, theta_at)`` of still targets at random pixels and orientations, ``depths`` m
    beyond the lens, every marker in view; with ``clear``, none able to hide another."""
    rng = np.random.default_rng(seed)
    scenes = []
    while len(scenes) < count:
        pixel = rng.uniform([150, 120], [1130, 840])
        pose_at = placed(pixel, rng.uniform(*depths), random_rotation(rng))
        points = markers(pose_at)
        if not MODEL.visible(MODEL.to_camera(points), margin=0.05).all():
            continue
        if clear and hidden_markers(MODEL, points, MARKER_RADIUS).any():
            continue
        scenes.append((pose_at, at(HOME)))
    return scenes


def arm_in_front_of_marker(index, pose_at):
    """Joint angles that put the end-effector's tip on the line of sight to marker ``index``,
    0.25 m in front of it."""
    lens = lens_position(MODEL)
    marker = markers(pose_at)[index]
    tip = marker + 0.25 * (lens - marker) / np.linalg.norm(lens - marker)
    solutions = kinematics.inverse_kinematics(tip)
    return at(solutions[kinematics.within_limits(solutions)][0])


def overlapping(offset):
    """``(pose_at, theta_at)``: marker 1 (0.1 m along the target's x-axis) behind marker 0 as
    seen from the lens, its line of sight ``offset`` m beside marker 0's (0: wholly hidden)."""
    centre = pixel_to_global(np.array([[700.0, 430.0]]), np.array([1.1]), MODEL)[0]
    away = centre - lens_position(MODEL)
    away /= np.linalg.norm(away)
    side = np.cross((0.0, 0.0, 1.0), away)
    x = away + offset / 0.1 * side / np.linalg.norm(side)
    x /= np.linalg.norm(x)
    y = np.cross((0.0, 0.0, 1.0), x)
    y /= np.linalg.norm(y)
    rotation = np.column_stack([x, y, np.cross(x, y)])
    return (lambda t: (centre, rotation)), at(ARM_AWAY)


@pytest.fixture(scope="module")
def cameras():
    windowed = RenderedCamera(MODEL, FEATURES)
    full = RenderedCamera(MODEL, FEATURES, RenderSettings(windowed=False))
    yield windowed, full
    windowed.close()
    full.close()


def assert_same(a: det.Detections, b: det.Detections) -> np.ndarray:
    """The windowed detections ``a`` are the full frame's ``b``: the same status, found mask and
    areas, and centroids equal bit for bit, except where TinyRenderer's float32 rasterisation
    drew one edge pixel differently (the areas then differ by 1). Returns where areas agree."""
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_array_equal(a.found, b.found)
    assert np.all(np.abs(a.areas - b.areas) <= 1)
    same = a.areas == b.areas
    np.testing.assert_array_equal(a.pixels[same], b.pixels[same])  # NaN where NaN
    np.testing.assert_allclose(a.pixels, b.pixels, atol=0.05)
    return same


# --- pure helpers -------------------------------------------------------------------------------


def test_settings_are_checked_and_map_to_pybullets_light():
    for bad in [
        {"marker_radius": 0.0},
        {"light_intensity": -0.1},
        {"image_noise": -1.0},
        {"exposure_s": -0.01},
        {"blur_subframes": 1},
        {"light_direction": (0.0, 0.0, 0.0)},
    ]:
        with pytest.raises(ValueError, match="RenderSettings|light_direction"):
            RenderSettings(**bad)
    assert RenderSettings().lighting() == Lighting()
    light = RenderSettings(light_direction=(3.0, 0.0, 4.0), light_intensity=0.3).lighting()
    np.testing.assert_allclose(light.source, (0.6, 0.0, 0.8))
    assert light.diffuse == pytest.approx(0.3 * Lighting().diffuse)
    assert light.ambient == Lighting().ambient
    np.testing.assert_allclose(RenderSettings(exposure_s=0.03).instants(1.0), [0.97, 0.98, 0.99, 1])
    np.testing.assert_array_equal(RenderSettings().instants(1.0), [1.0])


def test_pixel_noise_is_a_function_of_the_pixel():
    key = 12345
    inner, outer = (100, 164, 200, 240), (90, 300, 190, 260)
    big = pixel_noise(key, 7, outer, WIDTH)
    np.testing.assert_array_equal(pixel_noise(key, 7, inner, WIDTH), big[10:50, 10:74])
    assert big.shape == (70, 210, 3)
    assert abs(big.mean()) < 0.02 and abs(big.std() - 1.0) < 0.02
    assert abs(np.corrcoef(big.ravel(), pixel_noise(key, 8, outer, WIDTH).ravel())[0, 1]) < 0.02
    assert not np.array_equal(big, pixel_noise(key + 1, 7, outer, WIDTH))
    assert np.abs(big).max() < 6.7


def test_exact_origin_keeps_the_detectors_float_sum_the_full_frames():
    assert exact_origin(0, 0, 700.3) is None
    assert exact_origin(600, 600, 700.3) is None  # one binade, [512, 1024)
    assert exact_origin(500, 520, 530.2) == 512  # the marker starts after 512: cut there
    assert exact_origin(500, 505, 530.2) == 0  # it straddles 512: pad to the edge
    assert exact_origin(500, 500, 511.5) == 0  # a hair below a power of two counts as above
    assert exact_origin(300, 300, 400.0) is None


def test_marker_windows_bound_each_marker_and_skip_the_unseen():
    centres = MODEL.to_camera(markers(placed((WIDTH - 60.0, 480.0), 1.2)))
    windows = marker_windows(MODEL, centres[None], MARKER_RADIUS)
    assert windows[1] is None  # 0.1 m to the right of marker 0: off the sensor
    image = sphere_image(centres[:1], MARKER_RADIUS, MODEL)
    (cu, cv), reach = image.centre[0], image.semi_major[0] + 2.0
    u0, u1, v0, v1 = windows[0]
    assert u0 <= cu - reach < u0 + 1 and u1 - 2 < cu + reach <= u1 - 1
    assert v0 <= cv - reach < v0 + 1 and v1 - 2 < cv + reach <= v1 - 1
    behind_lens = MODEL.to_global(np.array([[0.0, -0.2, 0.0]]))
    assert marker_windows(MODEL, MODEL.to_camera(behind_lens)[None], MARKER_RADIUS) == [None]
    centre = MODEL.to_camera(markers(placed((640.0, 480.0), 1.2)))[:1]
    still = marker_windows(MODEL, centre[None], MARKER_RADIUS)[0]
    moving = np.stack([centre, centre + [0.05, 0.0, 0.0]])  # two sub-frames 0.05 m apart
    wide = marker_windows(MODEL, moving, MARKER_RADIUS)[0]
    shift = 0.05 * MODEL.focal_length / MODEL.pixel_pitch / 1.2
    assert wide[0] == still[0] and wide[1] - still[1] == pytest.approx(shift, abs=1.5)


def test_window_keeps_only_the_spheres_that_can_show_in_it():
    def at_pixel(u, v, depth):
        return MODEL.to_camera(pixel_to_global(np.array([[u, v]]), np.array([depth]), MODEL))[0]

    reach = 0.01 * MODEL.focal_length / MODEL.pixel_pitch  # a 0.01 m sphere's radius at 1 m, px
    centres = np.array(
        [
            at_pixel(620.0, 420.0, 1.0),  # in the first window
            at_pixel(900.0, 420.0, 1.0),  # in the second
            at_pixel(639.0 + reach, 420.0, 1.0),  # reaching into the first's last column
            at_pixel(642.0 + reach, 420.0, 1.0),  # clear of it by a pixel and a half
            at_pixel(900.0, 420.0, 0.04),  # not beyond the near plane: always drawn
        ]
    )
    windows = [(600, 640, 400, 440), (880, 920, 400, 440)]
    keeps = window_keeps(MODEL, windows, centres, np.full(5, 0.01))
    np.testing.assert_array_equal(keeps, [[1, 0, 1, 0, 1], [0, 1, 0, 0, 1]])


# --- rendered frames ----------------------------------------------------------------------------


def test_found_markers_agree_with_eq2(cameras):
    windowed, _ = cameras
    state = windowed.reset()
    rng = np.random.default_rng(0)
    analytic = Camera(MODEL, noise_px=0.0)
    for pose_at, _ in random_scenes(4, seed=1, depths=(0.8, 1.1), clear=True):
        frame = windowed.capture(state, pose_at, 0.0, at(ARM_AWAY), rng, 0)
        assert isinstance(frame, RenderedFrame) and isinstance(frame, Frame)
        truth = analytic.capture(analytic.reset(), markers(pose_at), np.random.default_rng(0))
        expected = truth.image_points
        assert frame.found.all() and (frame.status == det.FOUND).all()
        error_px = np.abs(frame.image_points - expected) / MODEL.pixel_pitch
        assert error_px.max() < 0.3


def test_windowed_detections_equal_the_full_frames(cameras):
    windowed, full = cameras
    edge = placed((10.0, 480.0), 1.2)  # marker 0 cut by the left edge, marker 2 near it
    straddle = placed((514.1, 513.8), 1.0)  # markers 0 and 1 span v = 512, marker 0 u = 512
    corner = placed((3.0, 955.0), 1.2)  # marker 0 cut by the corner
    occluded = random_scenes(1, seed=6, depths=(1.3, 1.5))[0][0]
    scenes = random_scenes(5, seed=2) + [
        (edge, at(HOME)),
        (straddle, at(HOME)),
        (corner, at(HOME)),
        (occluded, arm_in_front_of_marker(1, occluded)),
        overlapping(0.008),
        overlapping(0.0),
    ]
    same = []
    statuses = []
    for pose_at, theta_at in scenes:
        a = windowed.detect(pose_at, 0.0, theta_at, 0)
        b = full.detect(pose_at, 0.0, theta_at, 0)
        same += assert_same(a, b).tolist()
        statuses.append(a.status)
    assert np.mean(same) > 0.9
    at_edge, _, in_corner, arm_in_front, half_behind, wholly_behind = statuses[5:]
    assert at_edge[0] == det.AT_BORDER and at_edge[2] == det.FOUND
    assert in_corner[0] in (det.AT_BORDER, det.NO_BLOB)
    assert arm_in_front[1] != det.FOUND and arm_in_front[0] == det.FOUND
    assert half_behind[1] in (det.PARTIAL, det.SPLIT)  # marker 1 half behind marker 0
    assert wholly_behind[1] in (det.NO_BLOB, det.TOO_SMALL, det.PARTIAL)


def test_the_arm_hides_a_marker_it_stands_in_front_of(cameras):
    """The tip on marker 1's line of sight hides it; a window over it, drawing only the shapes
    that can reach it, has the full frame's pixels."""
    windowed, full = cameras
    pose_at = random_scenes(1, seed=6, depths=(1.3, 1.5))[0][0]
    theta_at = arm_in_front_of_marker(1, pose_at)
    clear = windowed.detect(pose_at, 0.0, at(HOME), 0)
    hidden = windowed.detect(pose_at, 0.0, theta_at, 0)
    assert clear.status[1] == det.FOUND
    assert hidden.status[1] in (det.NO_BLOB, det.TOO_SMALL, det.PARTIAL, det.SPLIT)
    assert np.isnan(hidden.pixels[1]).all()
    u, v = (int(round(c)) for c in true_pixels(pose_at)[1])
    window = (u - 40, u + 40, v - 40, v + 40)
    part = windowed.image(pose_at, 0.0, theta_at, 0, window)
    whole = full.image(pose_at, 0.0, theta_at, 0)[v - 40 : v + 40, u - 40 : u + 40]
    assert len(np.unique(part.reshape(-1, 3), axis=0)) > 3  # the tip, the arm, a marker's rim
    assert np.count_nonzero(np.any(part != whole, axis=2)) <= 2  # float32 edge pixels at most


def test_unseen_markers_are_missing_and_a_frame_needs_one_found(cameras):
    windowed, _ = cameras
    state = windowed.reset()
    rng = np.random.default_rng(0)
    half_off = placed((WIDTH - 60.0, 480.0), 1.2)  # marker 1 off the sensor
    frame = windowed.capture(state, half_off, 0.0, at(HOME), rng, 0)
    assert frame is not None and not state.last_visible
    assert frame.found[0] and not frame.found[1] and frame.status[1] == det.NO_BLOB
    assert np.isnan(frame.image_points[1]).all()
    camera_back = MODEL.position - 0.3 * MODEL.rotation[:, 1]  # behind the lens
    gone = lambda t: (camera_back, np.eye(3))  # noqa: E731
    assert windowed.capture(state, gone, 0.0, at(HOME), rng, 1) is None
    assert (state.last_detections.status == det.NO_BLOB).all()
    assert not state.last_visible and not state.last_dropped


def test_dropout_and_latency_follow_the_analytic_camera():
    pose_at, theta_at = random_scenes(1, seed=3, depths=(0.8, 1.0), clear=True)[0]
    theta_at = at(ARM_AWAY)
    points = markers(pose_at)
    analytic = Camera(MODEL, noise_px=0.0, dropout=0.4, latency_frames=2)
    with RenderedCamera(MODEL, FEATURES, dropout=0.4, latency_frames=2) as rendered:
        state, expected = rendered.reset(), analytic.reset()
        delivered = dropped = 0
        for k in range(10):
            a = analytic.capture(expected, points, np.random.default_rng(100 + k))
            b = rendered.capture(state, pose_at, 0.0, theta_at, np.random.default_rng(100 + k), k)
            assert (a is None) == (b is None), k
            assert state.last_dropped == expected.last_dropped
            assert state.last_visible == expected.last_visible
            if a is not None:
                delivered += 1
                assert b.capture_index == a.capture_index
                error = np.abs(b.image_points - a.image_points) / MODEL.pixel_pitch
                assert b.found.all() and error.max() < 0.3
            dropped += expected.last_dropped
        assert delivered >= 2 and dropped >= 2


def test_capture_draws_one_uniform_whatever_the_scene():
    scenes = [
        random_scenes(1, seed=4)[0][0],
        lambda t: (MODEL.position - 0.3 * MODEL.rotation[:, 1], np.eye(3)),  # behind the lens
        placed((WIDTH - 60.0, 480.0), 1.2),
    ]
    reference = np.random.default_rng(9)
    reference.random()
    with RenderedCamera(MODEL, FEATURES, RenderSettings(image_noise=4.0), dropout=0.5) as camera:
        state = camera.reset(np.random.default_rng(1))
        for pose_at in scenes:
            for seed in (9, 10, 11):  # some of these captures are dropped
                rng = np.random.default_rng(seed)
                camera.capture(state, pose_at, 0.0, at(HOME), rng, 0)
                check = np.random.default_rng(seed)
                check.random()
                assert rng.bit_generator.state == check.bit_generator.state
        reset_rng = np.random.default_rng(5)
        state = camera.reset(reset_rng)  # the noise key: one draw
        check = np.random.default_rng(5)
        assert state.noise_key == int(check.integers(0, 2**64, dtype=np.uint64))
        assert reset_rng.bit_generator.state == check.bit_generator.state


def test_image_noise_is_the_same_in_a_window_and_the_full_frame():
    pose_at, theta_at = random_scenes(1, seed=5, depths=(0.9, 1.0))[0]
    noisy_settings = RenderSettings(image_noise=6.0)
    with (
        RenderedCamera(MODEL, FEATURES, noisy_settings) as noisy,
        RenderedCamera(MODEL, FEATURES, RenderSettings(windowed=False, image_noise=6.0)) as full,
        RenderedCamera(MODEL, FEATURES) as clean,
    ):
        episode = noisy.reset(np.random.default_rng(2))
        assert full.reset(np.random.default_rng(2)) == episode
        key = episode.noise_key
        u, v = (int(round(c)) for c in true_pixels(pose_at)[0])
        window = (u - 30, u + 30, v - 30, v + 30)
        crop = np.s_[v - 30 : v + 30, u - 30 : u + 30]
        part = noisy.image(pose_at, 0.0, theta_at, 3, window, key)
        plain = clean.image(pose_at, 0.0, theta_at, 3, window)
        whole = full.image(pose_at, 0.0, theta_at, 3, noise_key=key)
        plain_whole = clean.image(pose_at, 0.0, theta_at, 3)

        def noised(image, window):  # the documented rule: add sigma * pixel_noise, round, clip
            z = 6.0 * pixel_noise(key, 3, window, WIDTH)
            return np.clip(np.rint(image + z), 0, 255).astype(np.uint8)

        np.testing.assert_array_equal(part, noised(plain, window))
        np.testing.assert_array_equal(whole, noised(plain_whole, (0, WIDTH, 0, HEIGHT)))
        drawn_alike = plain == plain_whole[crop]  # TinyRenderer may differ on an edge pixel
        assert drawn_alike.mean() > 0.99
        np.testing.assert_array_equal(part[drawn_alike], whole[crop][drawn_alike])
        assert not np.array_equal(part, noisy.image(pose_at, 0.0, theta_at, 4, window, key))
        residual = part.astype(float) - plain
        unclipped = (plain > 30) & (plain < 225)
        assert 5.0 < residual[unclipped].std() < 7.0
        assert_same(
            noisy.detect(pose_at, 0.0, theta_at, 3, episode),
            full.detect(pose_at, 0.0, theta_at, 3, episode),
        )


def test_motion_blur_puts_the_centroid_between_the_sub_frame_positions():
    start = pixel_to_global(np.array([[600.0, 450.0]]), np.array([1.2]), MODEL)[0]
    velocity = 0.2 * MODEL.rotation[:, 0]  # 4 mm across the image in 20 ms: 7 px

    def pose_at(t):
        return start + velocity * (t - 1.0), np.eye(3)

    settings = RenderSettings(exposure_s=0.02)
    with (
        RenderedCamera(MODEL, FEATURES, settings) as blurred,
        RenderedCamera(MODEL, FEATURES, RenderSettings(exposure_s=0.02, windowed=False)) as full,
    ):
        found = blurred.detect(pose_at, 1.0, at(ARM_AWAY), 0)
        first, last = true_pixels(pose_at, 0.98), true_pixels(pose_at, 1.0)
        assert found.found[0]
        step = last[0] - first[0]
        along = (found.pixels[0] - first[0]) @ step / (step @ step)
        offset = found.pixels[0] - first[0]
        across = (step[0] * offset[1] - step[1] * offset[0]) / np.linalg.norm(step)
        assert 0.3 < along < 0.7 and abs(across) < 0.5
        assert_same(found, full.detect(pose_at, 1.0, at(ARM_AWAY), 0))


@pytest.mark.parametrize(
    "settings",
    [
        RenderSettings(light_direction=(1.0, 0.0, 0.0)),
        RenderSettings(light_direction=(0.0, -0.3, 1.0)),
        RenderSettings(light_intensity=0.3),
    ],
    ids=["side", "above", "dim"],
)
def test_markers_are_found_under_other_light(settings):
    with RenderedCamera(MODEL, FEATURES, settings) as camera:
        for pose_at, _ in random_scenes(3, seed=7, depths=(0.8, 1.1), clear=True):
            found = camera.detect(pose_at, 0.0, at(ARM_AWAY), 0)
            assert found.found.all()
            error = np.linalg.norm(found.pixels - true_pixels(pose_at), axis=1)
            assert error[found.found].max() < 0.3


def test_the_target_block_hides_markers_in_both_paths():
    with (
        RenderedCamera(MODEL, FEATURES, RenderSettings(target_block=True)) as windowed,
        RenderedCamera(MODEL, FEATURES, RenderSettings(target_block=True, windowed=False)) as full,
        RenderedCamera(MODEL, FEATURES) as bare,
    ):
        hidden = 0
        for pose_at, theta_at in random_scenes(4, seed=8, depths=(0.8, 1.0)):
            a = windowed.detect(pose_at, 0.0, theta_at, 0)
            assert_same(a, full.detect(pose_at, 0.0, theta_at, 0))
            hidden += int((~a.found & bare.detect(pose_at, 0.0, theta_at, 0).found).sum())
        assert hidden >= 1


def test_the_benchmark_prints_its_tables(monkeypatch, capsys):
    path = Path(__file__).parents[1] / "benchmarks" / "bench_rendered_sensor.py"
    spec = importlib.util.spec_from_file_location("bench_rendered_sensor", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    monkeypatch.setattr(bench.os, "sched_setaffinity", lambda *args: None)  # keep pytest's CPUs
    assert bench.main(["--poses", "2", "--timing-poses", "3", "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    for row in ["windowed", "full frame", "render", "detect", "the rest", "default"]:
        assert row in out
    for row in ["noise 8 grey levels", "exposure 20 ms, 0.05 m/s", "intensity 0.3", "from +x"]:
        assert row in out
