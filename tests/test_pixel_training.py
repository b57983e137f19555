"""Training, storing and evaluating a policy that sees the camera's pixels (``observation_source
"pixels"``): the batched training env against SB3's ``DummyVecEnv`` of single envs, a tiny
``train.py`` run whose policy loads without unpickling and evaluates through ``evaluate.py``,
the batched evaluation against the single env, and the one-line refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

import evaluate
import train
from capture_bench.agents.policy_file import PolicyLoadError, parse_declaration
from capture_bench.agents.sb3_policy import (
    SB3Policy,
    load_policy,
    load_sb3_policy,
    load_trusted,
    read_metadata,
)
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.task.scenarios import load_scenario
from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv
from capture_bench.training.seeds import TrainingSeeds

SIZE = 36  # a small image keeps the tiny runs fast; the default is 84
TINY = ["n_envs=2", "n_steps=32", "batch_size=32", "n_epochs=1", "policy_kwargs.net_arch=[8]"]
TINY += [f"image_size={SIZE}", "total_timesteps=64", "checkpoint_freq=64", "eval_freq=64"]
TINY += ["eval_episodes=2"]
PIXELS = ["--observation-source", "pixels", "--config", "configs/pixels/ppo.yaml"]


#: The pixel observation's options (a frame stack and an end-effector crop), as train.py keys.
OPTIONS = ["frame_stack=2", "ee_crop=36", "ee_crop_scale=2", "ee_crop_supersample=2"]


@pytest.fixture(scope="module")
def pixel_run(tmp_path_factory):
    """A tiny PPO run on paper's pixels, with its checkpoint and periodic validation."""
    run_dir = tmp_path_factory.mktemp("pixels") / "run"
    argv = [*PIXELS, *(f"--set={s}" for s in TINY), "--run-dir", str(run_dir)]
    assert train.main(argv) == 0
    return run_dir


@pytest.fixture(scope="module")
def options_run(tmp_path_factory):
    """The same tiny run with the pixel observation's options (`OPTIONS`)."""
    run_dir = tmp_path_factory.mktemp("pixels") / "options"
    argv = [*PIXELS, *(f"--set={s}" for s in TINY + OPTIONS), "--run-dir", str(run_dir)]
    assert train.main(argv) == 0
    return run_dir


def test_the_batched_training_env_gives_the_single_envs_transitions():
    scenario = load_scenario("paper").replace(control={"episode_limit": 1.0})
    n, seed = 2, 5
    ref = DummyVecEnv([
        (lambda i=i: TrainingSeeds(
            CaptureEnv(scenario, reuse_target_side=True, observation_source="pixels",
                       image_size=(SIZE, SIZE)),
            scenario, seed=seed * 1000 + i))
        for i in range(n)
    ])  # fmt: skip
    got = CaptureSB3VecEnv(
        n, scenario, seed=seed, observation_source="pixels", image_size=(SIZE,) * 2
    )
    obs, obs_b = ref.reset(), got.reset()
    rng = np.random.default_rng(0)
    resets = 0
    for step in range(50):
        np.testing.assert_array_equal(obs_b["image"], obs["image"], err_msg=f"step {step}")
        np.testing.assert_allclose(obs_b["state"], obs["state"], rtol=1e-6, atol=1e-7)
        actions = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
        obs, rewards, dones, infos = ref.step(actions)
        obs_b, rewards_b, dones_b, infos_b = got.step(actions)
        np.testing.assert_array_equal(dones_b, dones)
        np.testing.assert_allclose(rewards_b, rewards, rtol=1e-6, atol=1e-9)
        for i in np.flatnonzero(dones).tolist():
            resets += 1
            final, final_b = infos[i]["terminal_observation"], infos_b[i]["terminal_observation"]
            assert set(final_b) == {"image", "state"}
            np.testing.assert_array_equal(final_b["image"], final["image"])
            np.testing.assert_allclose(final_b["state"], final["state"], rtol=1e-6, atol=1e-7)
    assert resets >= 2  # each sub-env went through a same-step reset
    ref.close()
    got.close()


def test_a_pixel_run_stores_a_dict_policy_that_loads_without_unpickling(pixel_run):
    meta = json.loads((pixel_run / "metadata.json").read_text())
    space = meta["observation_space"]
    assert space["type"] == "Dict" and meta["observation_source"] == "pixels"
    assert space["spaces"]["image"] == {
        "type": "Box", "shape": [3, SIZE, SIZE], "dtype": "uint8", "low": 0, "high": 255,
    }  # fmt: skip
    assert space["spaces"]["state"]["shape"] == [7]
    assert meta["policy_kwargs"]["features_extractor"] == "combined"
    metadata = read_metadata(pixel_run)
    assert metadata.image_size == (SIZE, SIZE)
    safe, trusted = load_policy(metadata), load_trusted(metadata)  # weights_only / SB3's .zip
    env = CaptureEnv("paper", observation_source="pixels", image_size=(SIZE, SIZE))
    obs, _ = env.reset(seed=load_scenario("paper").validation_seeds[0])
    for _ in range(5):
        a = SB3Policy(safe.policy).predict(obs)[0]
        np.testing.assert_array_equal(a, SB3Policy(trusted.policy).predict(obs)[0])
        obs = env.step(a)[0]
    env.close()
    assert (pixel_run / "best" / "policy.pt").is_file()  # the periodic validation's best
    assert any((pixel_run / "checkpoints").iterdir())


def test_a_pixel_run_resumes_from_its_checkpoint(pixel_run, tmp_path):
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(pixel_run, copy)
    assert train.main(["--resume", str(copy), "--total-timesteps", "128"]) == 0
    assert json.loads((copy / "metadata.json").read_text())["total_timesteps"] >= 128


def test_a_run_with_pixel_options_records_them_and_loads_without_unpickling(options_run):
    meta = json.loads((options_run / "metadata.json").read_text())
    assert meta["pixel_observation"] == {
        "frame_stack": 2, "ee_crop": 36, "ee_crop_scale": 2, "ee_crop_supersample": 2,
    }  # fmt: skip
    shapes = {k: v["shape"] for k, v in meta["observation_space"]["spaces"].items()}
    assert shapes == {"ee_image": [6, 36, 36], "image": [6, SIZE, SIZE], "state": [7]}
    metadata = read_metadata(options_run)
    assert metadata.image_size == (SIZE, SIZE)
    env_options = metadata.env_options
    assert env_options["frame_stack"] == 2 and env_options["ee_crop"] == 36
    safe, trusted = load_policy(metadata), load_trusted(metadata)
    env = CaptureEnv("paper", **env_options)
    obs, _ = env.reset(seed=load_scenario("paper").validation_seeds[0])
    for _ in range(3):
        a = SB3Policy(safe.policy).predict(obs)[0]
        np.testing.assert_array_equal(a, SB3Policy(trusted.policy).predict(obs)[0])
        obs = env.step(a)[0]
    env.close()
    bad = dict(meta, pixel_observation={"frame_stack": 0})
    (options_run / "metadata.json").write_text(json.dumps(bad))
    try:
        with pytest.raises(PolicyLoadError, match="frame_stack must be a whole number") as caught:
            read_metadata(options_run)
        assert len(str(caught.value).splitlines()) == 1
    finally:
        (options_run / "metadata.json").write_text(json.dumps(meta))


@pytest.mark.parametrize("run", ["pixel_run", "options_run"])
def test_a_pixel_model_evaluates_through_evaluate_py_in_pixel_envs(run, request, tmp_path):
    model = request.getfixturevalue(run)
    out = tmp_path / "reports"
    argv = ["--agents", "incremental_ik", str(model), "--scenarios", "paper"]
    argv += ["--episodes", "3", "--workers", "1", "--out", str(out)]
    assert evaluate.main(argv) == 0
    rows = (next(out.rglob("episodes.csv"))).read_text().splitlines()
    assert sum(row.startswith(f"{model.name} (pixels),paper,") for row in rows) == 3


@pytest.mark.parametrize("run", ["pixel_run", "options_run"])
def test_the_batched_evaluation_of_a_pixel_model_equals_the_single_env(run, request):
    pixel_run = request.getfixturevalue(run)
    from capture_bench.evaluation.running.backends import (
        EpisodeTask,
        close_envs,
        run_batch,
        run_task,
    )

    seeds = load_scenario("paper").evaluation_seeds[:3]
    tasks = [EpisodeTask(str(pixel_run), "paper", seed) for seed in seeds]
    try:
        batched = run_batch(tasks)
        single = [run_task(task)[0] for task in tasks]
    finally:
        close_envs()
    for a, b in zip(batched, single, strict=True):
        row_a, row_b = a.as_row(), b.as_row()
        for key in ("wall_clock_s", "cpu_s"):
            row_a.pop(key), row_b.pop(key)
        assert repr(row_a) == repr(row_b)


def test_a_pixel_model_in_an_estimate_env_and_the_reverse_are_one_line(pixel_run):
    estimate = CaptureEnv("paper")
    pixels = CaptureEnv("paper", observation_source="pixels")
    try:
        with pytest.raises(PolicyLoadError) as caught:
            load_sb3_policy(pixel_run, estimate)
        text = str(caught.value)
        assert "pixels" in text and "observation_source='pixels'" in text
        assert len(text.splitlines()) == 1
        with pytest.raises(PolicyLoadError) as caught:
            load_sb3_policy("models/dagger-dls-paper", pixels)
        assert "estimate" in str(caught.value) and len(str(caught.value).splitlines()) == 1
    finally:
        estimate.close()
        pixels.close()


def test_a_model_with_pixel_options_in_a_plain_pixel_env_is_one_line(options_run):
    plain = CaptureEnv("paper", observation_source="pixels", image_size=(SIZE, SIZE))
    try:
        with pytest.raises(PolicyLoadError) as caught:
            load_sb3_policy(options_run, plain)
        text = str(caught.value)
        assert "pixel_observation" in text and "ee_image" in text
        assert len(text.splitlines()) == 1
    finally:
        plain.close()


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--observation-source", "pixels"], ["MultiInputPolicy", "configs/pixels/ppo.yaml"]),
        (["--algo", "sac", "--observation-source", "pixels", "--set", "policy=MultiInputPolicy",
          "--set", "policy_kwargs.features_extractor=combined"], ["replay buffer", "ppo or a2c"]),
        ([*PIXELS, "--scenario", "all"], ["one scenario"]),
        ([*PIXELS, "--set", "normalize=true"], ["normalize"]),
        ([*PIXELS, "--set", "residual=incremental_ik"], ["residual"]),
        (["--set", "policy=MultiInputPolicy", "--set", "policy_kwargs.features_extractor=combined"],
         ["--observation-source pixels"]),
        (["--set", "image_size=64"], ["image_size", "pixels"]),
        (["--scenario", "all", "--set", "policy=MultiInputPolicy",
          "--set", "policy_kwargs.features_extractor=combined"], ["--observation-source pixels"]),
        (["--set", "policy=MultiInputPolicy"], ["features_extractor", "combined"]),
        ([*PIXELS, "--set", "image_size=20"], ["image_size", "36"]),  # below NatureCNN's
        (["--set", "frame_stack=3"], ["'frame_stack'", "--observation-source pixels"]),
        ([*PIXELS, "--set", "ee_crop=20"], ["ee_crop", "36"]),
        ([*PIXELS, "--set", "ee_crop=200", "--set", "ee_crop_scale=5"], ["shorter side"]),
    ],
)  # fmt: skip
def test_a_bad_pixel_training_setup_is_one_line(tmp_path, capsys, argv, words):
    assert train.main([*argv, "--run-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    for word in words:
        assert word in err, (word, err)
    assert not (tmp_path / "r").exists()


def test_a_declared_image_must_be_uint8_from_0_to_255(pixel_run):
    meta = json.loads((pixel_run / "metadata.json").read_text())
    parse_declaration(meta, "m")  # as written
    meta["observation_space"]["spaces"]["image"]["high"] = 1
    with pytest.raises(PolicyLoadError, match="0 and 255"):
        parse_declaration(meta, "m")
    meta["observation_space"]["spaces"]["image"]["high"] = 255
    meta["normalization"] = {"mean": [0.0], "var": [1.0], "epsilon": 1e-8, "clip_obs": 10.0}
    with pytest.raises(PolicyLoadError, match="null for a Dict"):
        parse_declaration(meta, "m")


def test_models_glob_leaves_pixel_models_to_be_named(pixel_run, tmp_path):
    import shutil

    from capture_bench.evaluation.running.agents_loading import expand_specs

    shutil.copytree(pixel_run, tmp_path / "px", ignore=shutil.ignore_patterns("checkpoints", "tb"))
    shutil.copytree("models/dagger-dls-paper", tmp_path / "dagger-dls-paper")
    found = expand_specs(["incremental_ik", "models/*"], tmp_path)
    assert found == ["incremental_ik", str(tmp_path / "dagger-dls-paper")]
    assert expand_specs([str(tmp_path / "px")], tmp_path) == [str(tmp_path / "px")]


def test_shipping_a_pixel_run_writes_a_card_that_replays_in_pixel_envs(pixel_run, tmp_path):
    from test_model_cards import _check_replay
    from test_safe_models import _assert_same_actions

    from capture_bench.training.train.model_card import ship

    target = ship(pixel_run, "px", episodes=2, out=tmp_path / "models")
    card = json.loads((target / "metadata.json").read_text())["model_card"]
    _check_replay(target, card, count=2)
    metadata = read_metadata(target)
    safe, trusted = load_policy(metadata), load_trusted(metadata)
    _assert_same_actions(SB3Policy(safe.policy), SB3Policy(trusted.policy))


def test_the_shipped_end_effector_config_sets_the_documented_pixel_options():
    from capture_bench.engine.task import CaptureTask
    from capture_bench.training.config.settings import resolve_settings

    for scenario in ("paper", "grasp"):
        settings, _, _ = resolve_settings(
            "ppo", load_scenario(scenario), "configs/pixels/ppo_ee.yaml"
        )
        options = settings.pixel_options
        assert options == {"image_size": (84, 84), "frame_stack": 3, "ee_crop": 37,
                           "ee_crop_scale": 3}  # fmt: skip
        task = CaptureTask(scenario, observation_source="pixels", **options)
        assert task.single_observation_space["ee_image"].shape == (9, 37, 37)
