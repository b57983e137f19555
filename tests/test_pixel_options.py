"""The pixel observation's options (`PixelOptions`): the end-effector crop follows the
end-effector, area sampling is the mean of its samples, the frame stack holds the last frames in
order and restarts with the episode, and bad values are refused in one line."""

from __future__ import annotations

import numpy as np
import pytest

from capture_bench.engine.task import CaptureTask
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.sensing.pixels import pixel_of
from capture_bench.sensing.workspace_image import area_mean, ee_window
from capture_bench.sim import kinematics
from capture_bench.validation import ConfigError

HOME = np.array([0.0, np.pi / 2, 0.0])
SMALL = (36, 36)  # the smallest image NatureCNN reads: the fastest env


def _poses(n: int, seed: int = 0):
    """Arm poses near home, whose end-effector the camera sees well inside its sensor, with the
    target away from it (not in the crop)."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        theta = HOME + rng.uniform(-0.3, 0.3, 3)
        x_e = kinematics.forward_kinematics(theta)
        yield theta, x_e, x_e + np.array([0.3, 0.3, 0.3]), np.eye(3)


@pytest.mark.parametrize(("n", "c"), [(25, 2), (31, 1)])
def test_the_end_effector_crop_is_centred_on_the_end_effectors_projection(n, c):
    task = CaptureTask("paper", observation_source="pixels", ee_crop=n, ee_crop_scale=c)
    model, imager = task.camera.model, task.imager()
    try:
        for theta, x_e, position, rotation in _poses(5):
            u, v = pixel_of(model.to_camera(x_e[None]), model)[0]
            u0, u1, v0, v1 = ee_window(model, x_e, n * c)
            assert (u1 - u0, v1 - v0) == (n * c, n * c)
            assert 0 < u0 and u1 < model.resolution[0] and 0 < v0 and v1 < model.resolution[1]
            # the centre crop pixel's centre (pixel-centre coordinates), within half a sensor
            # pixel of the projection: the crop's tolerance, stated in the module docstring
            centre = np.array([u0, v0]) + c * (n // 2) + (c - 1) / 2
            assert np.all(np.abs(centre - [u, v]) <= 0.5 + 1e-9)
            image = imager.render_ee(theta, position, rotation, x_e)
            r, g, b = (int(x) for x in image[:, n // 2, n // 2])
            assert r > 180 and r > g > b and b < 100  # the gripper's orange, not the floor
    finally:
        imager.close()


def test_the_end_effector_crop_is_the_same_cameras_pixels():
    """At full density the crop is the full-density render of the wide crop, cut at its
    window (two frustums rasterised apart: a pixel on an edge may differ)."""
    task = CaptureTask("paper", observation_source="pixels", ee_crop=41, image_size=SMALL)
    model, imager = task.camera.model, task.imager()
    big_u0, _, big_v0, _ = imager.window
    try:
        for theta, x_e, position, rotation in _poses(2, seed=3):
            crop = imager.render_ee(theta, position, rotation, x_e).transpose(1, 2, 0)
            full = imager.full_density(theta, position, rotation)
            u0, u1, v0, v1 = ee_window(model, x_e, 41)
            cut = full[v0 - big_v0 : v1 - big_v0, u0 - big_u0 : u1 - big_u0]
            assert np.count_nonzero(np.any(crop != cut, axis=-1)) <= 8
            assert len(np.unique(crop.reshape(-1, 3), axis=0)) > 3  # not blank
    finally:
        imager.close()


def test_area_sampling_is_the_rounded_mean_of_the_m_by_m_samples():
    rgba = np.zeros((4, 6, 4), np.uint8)
    rgba[..., 0] = np.arange(24).reshape(4, 6) * 10
    image = area_mean(rgba.ravel(), (3, 2), 2)
    block = rgba[..., 0].reshape(2, 2, 3, 2).mean(axis=(1, 3))
    np.testing.assert_array_equal(image[0], np.floor(block + 0.5).astype(np.uint8))
    # a crop at scale 2 with 2 x 2 samples is the 2 x 2 mean of the same window at full density
    coarse = CaptureTask(
        "paper", observation_source="pixels", ee_crop=20, ee_crop_scale=2, ee_crop_supersample=2
    )
    fine = CaptureTask("paper", observation_source="pixels", ee_crop=40)
    a, b = coarse.imager(), fine.imager()
    try:
        for theta, x_e, position, rotation in _poses(2, seed=5):
            big = b.render_ee(theta, position, rotation, x_e).transpose(1, 2, 0)
            flat = np.concatenate([big, np.zeros((40, 40, 1), np.uint8)], -1).ravel()
            expected = area_mean(flat, (20, 20), 2)
            assert np.array_equal(a.render_ee(theta, position, rotation, x_e), expected)
    finally:
        a.close()
        b.close()


def test_the_wide_image_supersampled_is_the_mean_of_a_render_m_times_its_size():
    """12 x 12 at m = 7 renders the same window at 84 x 84 (s = 77 = 7 x 11), then averages."""
    point = CaptureTask("paper", observation_source="pixels")
    area = CaptureTask(
        "paper", observation_source="pixels", image_size=(12, 12), image_supersample=7
    )
    a, b = area.imager(), point.imager()
    try:
        assert a.window == b.window
        theta, x_e, _, rotation = next(_poses(1))
        image84 = b.render(theta, x_e + 0.02, rotation)
        flat = np.concatenate([image84.transpose(1, 2, 0), np.zeros((84, 84, 1), np.uint8)], -1)
        expected = area_mean(flat.ravel(), (12, 12), 7)
        assert np.array_equal(a.render(theta, x_e + 0.02, rotation), expected)
    finally:
        a.close()
        b.close()


def _frames(image: np.ndarray, k: int) -> list[np.ndarray]:
    return [image[3 * i : 3 * i + 3] for i in range(k)]


def test_the_stack_holds_the_last_frames_in_order_and_restarts_with_the_episode():
    k = 3
    kwargs = {"observation_source": "pixels", "image_size": SMALL}
    with (
        CaptureEnv("paper", frame_stack=k, ee_crop=37, **kwargs) as stacked,
        CaptureEnv("paper", ee_crop=37, **kwargs) as single,
    ):
        assert stacked.observation_space["image"].shape == (3 * k, 36, 36)
        assert stacked.observation_space["ee_image"].shape == (3 * k, 37, 37)
        for seed in (4, 5):  # the second reset restarts the stack
            obs, _ = stacked.reset(seed=seed)
            one, _ = single.reset(seed=seed)
            seen = {key: [one[key]] for key in ("image", "ee_image")}
            for key in seen:
                assert all(np.array_equal(f, one[key]) for f in _frames(obs[key], k))
            for step, action in enumerate(np.random.default_rng(seed).uniform(-1, 1, (4, 3))):
                obs, *_ = stacked.step(action)
                one, *_ = single.step(action)
                for key in seen:
                    seen[key].append(one[key])
                    last = seen[key][-k:]
                    last = [last[0]] * (k - len(last)) + last
                    assert all(np.array_equal(f, e) for f, e in zip(_frames(obs[key], k), last)), (
                        key,
                        step,
                    )
                np.testing.assert_array_equal(obs["state"], one["state"])
            assert stacked.observation_space.contains(obs)


def test_the_batched_stack_restarts_each_sub_env_with_its_episode():
    kwargs = {"observation_source": "pixels", "image_size": SMALL}
    env = CaptureVectorEnv(2, "paper", frame_stack=2, autoreset_mode="Disabled", **kwargs)
    try:
        obs, _ = env.reset(seed=[7, 8])
        first = obs["image"].copy()
        obs, *_ = env.step(np.ones((2, 3)))
        assert np.array_equal(obs["image"][:, :3], first[:, 3:])
        newest = obs["image"][:, 3:].copy()
        mask = np.array([True, False])
        obs, _ = env.reset(seed=[9, 0], options={"reset_mask": mask})
        assert np.array_equal(obs["image"][0, :3], obs["image"][0, 3:])  # restarted
        assert np.array_equal(obs["image"][1, 3:], newest[1])  # untouched: not stepped
        assert not np.array_equal(obs["image"][1, :3], obs["image"][1, 3:])
    finally:
        env.close()


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"frame_stack": 0}, "frame_stack must be a whole number from 1 to 16; got 0"),
        ({"ee_crop": 2.5}, "ee_crop must be a whole number from 0 to 256; got 2.5"),
        ({"ee_crop_scale": 12}, "ee_crop_scale must be a whole number from 1 to 11"),
        ({"image_supersample": True}, "image_supersample must be a whole number"),
        ({"ee_crop": 200, "ee_crop_scale": 5}, "more than the sensor's shorter side, 960"),
    ],
)
def test_a_bad_pixel_option_is_one_clear_line(kwargs, words):
    with pytest.raises(ValueError, match=words) as caught:
        CaptureEnv("paper", observation_source="pixels", **kwargs)
    assert "\n" not in str(caught.value)


def test_a_pixel_option_without_pixels_is_refused():
    with pytest.raises(
        ConfigError, match='frame_stack=3 applies only with observation_source="pixels"'
    ):
        CaptureVectorEnv(2, "paper", frame_stack=3)


def test_the_envelopes_tolerance_spans_several_crop_pixels_across_the_view():
    """configs/pixels/ppo_ee.yaml's crop (3 sensor pixels a pixel): paper's 10 mm across the
    camera's view moves the end-effector's projection by about 6 crop pixels (grasp's 5 mm by 3);
    along the line of sight, by under a sensor pixel (depth is read from sizes and the stack)."""
    model = CaptureTask("paper").camera.model
    x_e = kinematics.forward_kinematics(HOME)

    def crop_pixels(step: np.ndarray) -> float:
        before, after = (pixel_of(model.to_camera(x[None]), model)[0] for x in (x_e, x_e + step))
        return float(np.linalg.norm(after - before)) / 3

    across = [crop_pixels(0.01 * model.rotation[:, axis]) for axis in (0, 2)]
    assert all(5.5 < n < 6.5 for n in across), across
    assert crop_pixels(0.01 * model.rotation[:, 1]) * 3 < 1.0  # the line of sight, sensor px
