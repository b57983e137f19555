"""The pixel observation (``observation_source="pixels"``): the image is the rendered camera's view
of the documented crop, sampled as documented; the state is the arm's true one; seeds replay the
same images in the single and the batched env; both env checkers pass."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from gymnasium import spaces

from capture_bench.engine.task import CaptureTask
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.sensing.pixels import pixel_of
from capture_bench.sensing.workspace_image import (
    WorkspaceImager,
    crop_scale,
    crop_window,
    sensor_pixels,
    wide_pixels,
)
from capture_bench.sim import kinematics

SEED = 12


@pytest.fixture
def env():
    env = CaptureEnv("paper", observation_source="pixels")
    yield env
    env.close()


def _actions(n: int, shape: tuple[int, ...] = (3,)) -> np.ndarray:
    return np.random.default_rng(5).uniform(-1.0, 1.0, (n, *shape)).astype(np.float32)


def _sampled(full: np.ndarray, s: int) -> np.ndarray:
    """Full-density pixels ``(s i + s // 2, s j + s // 2)``, channel-first."""
    return full[s // 2 :: s, s // 2 :: s].transpose(2, 0, 1)


def test_the_crop_of_the_shipped_camera_is_the_documented_one():
    model = CaptureTask("paper").camera.model
    assert crop_scale(model, (84, 84)) == 11
    assert crop_window(model, (84, 84)) == (255, 1179, 18, 942)
    assert crop_scale(model, (64, 64)) == 13  # odd: 14 would not sample pixel centres
    for size in [(84, 84), (64, 48), (36, 36), (1, 924)]:
        u0, u1, v0, v1 = crop_window(model, size)
        s = crop_scale(model, size)
        assert s % 2 == 1 and (u1 - u0, v1 - v0) == (s * size[0], s * size[1])
        assert 0 <= u0 and u1 <= 1280 and 0 <= v0 and v1 <= 960


@pytest.mark.parametrize("size", [(84, 84), (64, 48)])
def test_wide_image_pixels_and_sensor_pixels_are_each_others_inverse(size):
    model = CaptureTask("paper").camera.model
    u0, _, v0, _ = crop_window(model, size)
    s = crop_scale(model, size)
    # wide pixel (j, i) shows sensor pixel (u0 + s j + s // 2, v0 + s i + s // 2): the sampled one
    assert np.array_equal(sensor_pixels(model, size, [[0, 0], [2, 1]]),
                          [[u0 + s // 2, v0 + s // 2], [u0 + 2 * s + s // 2, v0 + s + s // 2]])  # fmt: skip
    wide = np.random.default_rng(1).uniform(-1.0, 84.0, (5, 3, 2))
    assert np.allclose(wide_pixels(model, size, sensor_pixels(model, size, wide)), wide, atol=1e-12)
    imager = WorkspaceImager(model, CaptureTask("paper").features, size)
    try:
        points = np.array([[0.5, 0.05, 0.3], [0.45, -0.02, 0.42]])
        uv = sensor_pixels(model, size, imager.image_points(points))
        assert np.allclose(uv, pixel_of(model.to_camera(points), model), atol=1e-9)
    finally:
        imager.close()


@pytest.mark.parametrize("size", [(84, 84), (48, 36)])
def test_the_image_is_the_full_density_render_of_the_crop_sampled_at_block_centres(size):
    task = CaptureTask("paper", observation_source="pixels", image_size=size)
    imager = task.imager()
    rng = np.random.default_rng(0)
    arm = task.description.arm
    try:
        s, differing = imager.scale, 0
        for _ in range(4):
            theta = rng.uniform(arm.joint_lower, arm.joint_upper)
            position = np.array([0.55, 0.0, 0.4]) + rng.uniform(-0.15, 0.15, 3)
            rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            image = imager.render(theta, position, rotation)
            assert image.shape == (3, size[1], size[0]) and image.dtype == np.uint8
            full = imager.full_density(theta, position, rotation)
            assert full.shape == (s * size[1], s * size[0], 3)
            differing += int(np.any(image != _sampled(full, s), axis=0).sum())
            assert np.unique(image.reshape(3, -1), axis=1).shape[1] > 3  # not blank
    finally:
        imager.close()
    # float32 rasterisation of two frustums: a pixel on a triangle's edge may differ
    assert differing <= 2


def test_the_env_image_is_the_crop_of_its_arm_and_true_target(env):
    imager = env.task.imager()
    try:
        obs, _ = env.reset(seed=SEED)
        for k, action in enumerate(_actions(6), start=1):
            obs, *_ = env.step(action)
            if k % 3:
                continue
            episode = env.recorded_episode
            args = (env.joint_angles, episode.position[k], episode.rotation[k])
            assert np.array_equal(obs["image"], imager.render(*args))
            full = imager.full_density(*args)
            assert np.count_nonzero(np.any(obs["image"] != _sampled(full, 11), axis=0)) <= 1
    finally:
        imager.close()


def test_the_state_is_the_true_joints_end_effector_and_period(env):
    obs, _ = env.reset(seed=SEED)
    t_s = env.description.control_period
    np.testing.assert_allclose(obs["state"][6], 1.0)
    for action in _actions(5):
        obs, _, _, _, info = env.step(action)
        theta = env.joint_angles
        x_e = kinematics.forward_kinematics(theta)
        expected = np.concatenate([theta / np.pi, x_e, [info["dt"] / t_s]])
        assert obs["state"].dtype == np.float32
        np.testing.assert_allclose(obs["state"], expected.astype(np.float32), rtol=0, atol=0)


def test_the_same_seed_gives_the_same_images_single_and_batched():
    actions = _actions(8)
    runs = []
    for _ in range(2):
        with CaptureEnv("paper", observation_source="pixels", reuse_target_side=True) as single:
            obs, _ = single.reset(seed=SEED)
            images = [obs["image"]] + [single.step(a)[0]["image"] for a in actions]
            runs.append(np.stack(images))
    assert np.array_equal(runs[0], runs[1])
    assert len({image.tobytes() for image in runs[0]}) > 1  # the arm moves
    batched = CaptureVectorEnv(2, "paper", observation_source="pixels")
    try:
        obs, _ = batched.reset(seed=[SEED, SEED + 1])
        images = [obs["image"][0]]
        for a in actions:
            other = np.zeros(3, np.float32)
            obs, *_ = batched.step(np.stack([a, other]))
            images.append(obs["image"][0])
    finally:
        batched.close()
    assert np.array_equal(np.stack(images), runs[0])


def test_info_is_the_estimator_envs(env):
    """The estimator still runs: ``info`` is that of the scenario's own source."""
    with CaptureEnv("paper") as reference:
        reference.reset(seed=SEED)
        env.reset(seed=SEED)
        for action in _actions(5):
            *_, info = env.step(action)
            *_, expected = reference.step(action)
            assert info.keys() == expected.keys()
            for key, value in expected.items():
                assert info[key] == value or (value != value and info[key] != info[key]), key


def test_spaces_are_the_documented_dicts():
    with CaptureEnv("paper", observation_source="pixels", image_size=(64, 48)) as single:
        space = single.observation_space
        assert isinstance(space, spaces.Dict) and set(space) == {"image", "state"}
        assert space["image"] == spaces.Box(0, 255, (3, 48, 64), np.uint8)
        assert space["state"] == spaces.Box(-10.0, 10.0, (7,), np.float32)
        obs, _ = single.reset(seed=0)
        assert space.contains(obs)
    batched = CaptureVectorEnv(3, "paper", observation_source="pixels", image_size=(64, 48))
    try:
        assert batched.single_observation_space == space
        assert batched.observation_space["image"].shape == (3, 3, 48, 64)
        assert batched.observation_space["state"].shape == (3, 7)
        obs, _ = batched.reset(seed=0)
        assert batched.observation_space.contains(obs)
        obs, *_ = batched.step(np.zeros((3, 3), np.float32))
        assert batched.observation_space.contains(obs)
    finally:
        batched.close()


@pytest.mark.parametrize(
    "options", [{}, {"frame_stack": 3, "ee_crop": 37, "ee_crop_scale": 2, "image_supersample": 2}]
)
def test_gymnasium_and_sb3_env_checkers_pass(options):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with CaptureEnv("paper", observation_source="pixels", **options) as env:
        check_env(env, skip_render_check=True)
    with (
        CaptureEnv("paper", observation_source="pixels", **options) as env,
        warnings.catch_warnings(),
    ):
        warnings.simplefilter("error")  # SB3's checker warns about what it would not train on
        sb3_check_env(env)


@pytest.mark.parametrize("bad", [(0, 84), (84,), "84x84", (84.0, 84), (925, 84), (84, True)])
def test_a_bad_image_size_is_one_clear_value_error(bad):
    with pytest.raises(ValueError, match=r"image_size must be \(width, height\), two whole"):
        CaptureEnv("paper", observation_source="pixels", image_size=bad)
    with pytest.raises(ValueError, match=r"image_size must be \(width, height\), two whole"):
        CaptureVectorEnv(2, "paper", observation_source="pixels", image_size=bad)


def test_an_unknown_observation_source_is_refused():
    with pytest.raises(ValueError, match="expected one of ekf, photogrammetry, truth, pixels"):
        CaptureEnv("paper", observation_source="image")


def test_the_imager_refuses_work_after_close():
    task = CaptureTask("paper", observation_source="pixels")
    imager: WorkspaceImager = task.imager()
    imager.close()
    imager.close()
    with pytest.raises(RuntimeError, match="closed"):
        imager.render(np.zeros(3), np.zeros(3), np.eye(3))


def test_the_benchmark_runs_and_prints_its_rows(capsys):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).parents[1] / "benchmarks" / "bench_pixels.py"
    spec = importlib.util.spec_from_file_location("bench_pixels", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    bench.main(["--num-envs", "2", "--seconds", "0.2", "--size", "36", "36"])
    rows = capsys.readouterr().out.splitlines()
    assert rows[1].split()[:2] == ["N", "pixels"]
    n, *figures = rows[2].split()
    assert n == "2" and all(float(f) > 0 for f in figures)
    options = ["--option", "frame_stack=2", "--option", "ee_crop=37"]
    bench.main(["--num-envs", "2", "--seconds", "0.2", "--size", "36", "36", *options])
    rows = capsys.readouterr().out.splitlines()
    assert rows[1] == "options: frame_stack=2, ee_crop=37" and "options steps/s" in rows[2]
    n, *figures = rows[3].split()
    assert n == "2" and len(figures) == 4 and all(float(f) > 0 for f in figures)
