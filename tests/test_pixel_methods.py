"""Methods pixel RL uses, as train.py options: DrQ's random shift changes the images of training
batches only (never the env's observations, the rollout buffer's or the stored policy's), and the
spatial-softmax extractor keeps the image's positions and is stored and loaded like every other."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import VecEnvWrapper

import train
from capture_bench.agents.features import SpatialSoftmax, SpatialSoftmaxExtractor
from capture_bench.agents.sb3_policy import load_policy, read_metadata
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.training.common.augmentation import install_random_shift, random_shift
from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv
from tests.stored_policies import (
    assert_evaluates_in_pixel_envs,
    assert_loads_safely_and_acts_as_trusted,
)

SIZE = 36
TINY = ["n_envs=2", "n_steps=16", "batch_size=16", "n_epochs=1", "policy_kwargs.net_arch=[8]",
        f"image_size={SIZE}", "total_timesteps=32", "checkpoint_freq=0", "eval_freq=0"]  # fmt: skip
PIXELS = ["--observation-source", "pixels", "--config", "configs/pixels/ppo.yaml"]


def test_a_random_shift_is_a_crop_of_the_edge_padded_image():
    images = torch.arange(2 * 3 * 6 * 5, dtype=torch.uint8).reshape(2, 3, 6, 5)
    assert random_shift(images, 0) is images
    padded = torch.nn.functional.pad(images.float(), (2, 2, 2, 2), mode="replicate")
    seen = set()
    for seed in range(40):
        out = random_shift(images, 2, torch.Generator().manual_seed(seed))
        assert out.shape == images.shape and out.dtype == torch.uint8
        for b in range(2):
            crops = {
                (dy, dx)
                for dy in range(5)
                for dx in range(5)
                if torch.equal(padded[b, :, dy : dy + 6, dx : dx + 5], out[b].float())
            }
            assert crops, "not a crop of the padded image"
            seen |= crops
    assert len(seen) > 15  # the offsets cover {0..4}^2


class _Recorder(VecEnvWrapper):
    """Keeps a copy of every observation the env gives."""

    def __init__(self, venv):
        super().__init__(venv)
        self.seen: list[dict[str, np.ndarray]] = []

    def reset(self):
        obs = self.venv.reset()
        self.seen.append({k: v.copy() for k, v in obs.items()})
        return obs

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        self.seen.append({k: v.copy() for k, v in obs.items()})
        return obs, rewards, dones, infos


def _model(venv, extractor: str = "combined"):
    from stable_baselines3 import PPO

    from capture_bench.agents.features import FEATURE_EXTRACTORS

    kwargs = {"net_arch": [8], "features_extractor_class": FEATURE_EXTRACTORS[extractor]}
    return PPO("MultiInputPolicy", venv, n_steps=16, batch_size=16, n_epochs=1, seed=0,
               policy_kwargs=kwargs, device="cpu")  # fmt: skip


def test_the_shift_changes_training_batches_only_never_the_envs_observations():
    venv = _Recorder(
        CaptureSB3VecEnv(
            2,
            "paper",
            seed=1,
            observation_source="pixels",
            image_size=(SIZE,) * 2,
            frame_stack=2,
            ee_crop=36,
            ee_crop_scale=2,
        )  # fmt: skip
    )
    model = _model(venv)
    policy = model.policy
    obs = venv.reset()
    batch, _ = policy.obs_to_tensor(obs)
    kept = {k: v.clone() for k, v in batch.items()}
    policy.set_training_mode(False)
    with torch.no_grad():
        plain = policy.extract_features(batch)
    handles = install_random_shift(policy, 4)
    with torch.no_grad():
        assert torch.equal(policy.extract_features(batch), plain)  # acting, validating: as is
        policy.set_training_mode(True)
        shifted = [policy.extract_features(batch) for _ in range(3)]
    assert not all(torch.equal(s, plain) for s in shifted)  # the updates see shifted images
    assert all(torch.equal(batch[k], kept[k]) for k in batch)  # the batch given is untouched
    venv.seen.clear()
    model.learn(total_timesteps=32)  # a rollout of 16 steps of 2 envs, then an update
    buffer = model.rollout_buffer.observations  # flattened for the update: (env, step) rows
    for key in ("image", "ee_image", "state"):
        rows = buffer[key].reshape(2, 16, *buffer[key].shape[1:])
        for t in range(16):  # after the update, still as the env gave them
            np.testing.assert_array_equal(rows[:, t], venv.seen[t][key])
    for handle in handles:
        handle.remove()
    venv.close()


def test_spatial_softmax_returns_the_expected_position_to_a_fraction_of_a_pixel():
    h, w = 21, 31
    ys, xs = torch.meshgrid(torch.arange(h).float(), torch.arange(w).float(), indexing="ij")
    centre = (7.3, 18.6)  # (row, column), pixels
    maps = -((ys - centre[0]) ** 2 + (xs - centre[1]) ** 2) / 2.0
    x, y = SpatialSoftmax()(maps[None, None]).reshape(2).tolist()
    assert (x + 1) / 2 * (w - 1) == pytest.approx(centre[1], abs=1e-3)
    assert (y + 1) / 2 * (h - 1) == pytest.approx(centre[0], abs=1e-3)


def test_the_keypoints_extractor_reads_every_image_and_keeps_positions():
    with CaptureEnv("paper", observation_source="pixels", image_size=(SIZE,) * 2,
                    ee_crop=37, frame_stack=2) as env:  # fmt: skip
        space = env.observation_space
        obs, _ = env.reset(seed=3)
    extractor = SpatialSoftmaxExtractor(space)
    assert extractor.features_dim == 32 + 32 + 7
    batch = {k: torch.as_tensor(v[None]).float() / (255 if v.dtype == np.uint8 else 1)
             for k, v in obs.items()}  # fmt: skip
    moved = dict(batch, image=torch.roll(batch["image"], 1, dims=-1))
    with torch.no_grad():
        a, b = extractor(batch), extractor(moved)
    assert a.shape == (1, 71) and not torch.equal(a[:, 32:64], b[:, 32:64])  # image keypoints
    assert torch.equal(a[:, :32], b[:, :32]) and torch.equal(a[:, 64:], b[:, 64:])


def test_a_run_with_the_shift_and_keypoints_stores_a_plain_policy_that_loads_safely(tmp_path):
    run = tmp_path / "run"
    sets = [*TINY, "augment_shift=4", "policy_kwargs.features_extractor=keypoints"]
    assert train.main([*PIXELS, *(f"--set={s}" for s in sets), "--run-dir", str(run)]) == 0
    meta = json.loads((run / "metadata.json").read_text())
    assert meta["policy_kwargs"]["features_extractor"] == "keypoints"
    assert meta["hyperparameters"]["augment_shift"] == 4
    assert_loads_safely_and_acts_as_trusted(run)


def test_the_shift_without_pixels_is_one_line(tmp_path, capsys):
    assert train.main(["--set", "augment_shift=4", "--run-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'augment_shift'" in err and "pixels" in err


# -- the asymmetric actor-critic: the critic reads the true state, the actor the pixels ---------


def test_the_true_observation_holds_the_true_target_and_the_arm():
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.task.observation import decode_observation

    env = CaptureVectorEnv(2, "paper", observation_source="pixels", image_size=(SIZE,) * 2)
    try:
        env.reset(seed=[3, 4])
        for action in np.random.default_rng(0).uniform(-1, 1, (5, 2, 3)):
            env.step(action)
            truth = decode_observation(env.true_observation(), env.description.control_period)
            for i in range(2):
                k = env.row_step(i)
                episode = env.row_episode(i)
                np.testing.assert_allclose(truth.target_position[i], episode.position[k], atol=1e-6)
                np.testing.assert_allclose(truth.target_velocity[i], episode.velocity[k], atol=1e-6)
    finally:
        env.close()


def _asymmetric():
    from stable_baselines3 import PPO

    from capture_bench.training.common.asymmetric import AsymmetricActorCriticPolicy

    venv = CaptureSB3VecEnv(2, "paper", seed=1, observation_source="pixels",
                            image_size=(SIZE,) * 2, critic_state=True)  # fmt: skip
    model = PPO(AsymmetricActorCriticPolicy, venv, n_steps=16, batch_size=16, n_epochs=1,
                seed=0, policy_kwargs={"net_arch": [8]}, device="cpu")  # fmt: skip
    return model, venv


def test_the_critic_reads_the_true_state_and_the_actor_does_not():
    model, venv = _asymmetric()
    try:
        obs = venv.reset()
        assert obs["critic_state"].shape == (2, 16)
        moved = dict(obs, critic_state=obs["critic_state"] + 1.0)
        policy = model.policy
        with torch.no_grad():
            values = [policy.predict_values(policy.obs_to_tensor(o)[0]) for o in (obs, moved)]
            means = [
                policy.get_distribution(policy.obs_to_tensor(o)[0]).distribution.mean
                for o in (obs, moved)
            ]
        assert not torch.equal(values[0], values[1])  # the critic reads the truth
        assert torch.equal(means[0], means[1])  # the actor does not
        without = {k: v for k, v in obs.items() if k != "critic_state"}  # validation's envs
        np.testing.assert_array_equal(policy.predict(without, deterministic=True)[0],
                                      policy.predict(obs, deterministic=True)[0])  # fmt: skip
    finally:
        venv.close()


def test_the_stored_policy_is_the_actor_and_the_critic_less_the_truth():
    from capture_bench.training.common.asymmetric import actor_policy

    model, venv = _asymmetric()
    try:
        model.learn(total_timesteps=32)  # trained weights, not the initial ones
        obs = venv.reset()
        plain = actor_policy(model.policy)
        assert "critic_state" not in plain.observation_space.spaces
        without = {k: v for k, v in obs.items() if k != "critic_state"}
        np.testing.assert_array_equal(plain.predict(without, deterministic=True)[0],
                                      model.policy.predict(obs, deterministic=True)[0])  # fmt: skip
        zeroed = dict(obs, critic_state=np.zeros_like(obs["critic_state"]))
        with torch.no_grad():
            stored = plain.predict_values(plain.obs_to_tensor(without)[0])
            trained = model.policy.predict_values(model.policy.obs_to_tensor(zeroed)[0])
        torch.testing.assert_close(stored, trained)  # the truth's inputs removed, nothing else
    finally:
        venv.close()


def test_an_asymmetric_run_stores_a_plain_pixel_policy_that_evaluates(tmp_path):
    run = tmp_path / "run"
    sets = [*TINY, "asymmetric_critic=true", "eval_freq=32", "eval_episodes=2"]
    assert train.main([*PIXELS, *(f"--set={s}" for s in sets), "--run-dir", str(run)]) == 0
    meta = json.loads((run / "metadata.json").read_text())
    assert set(meta["observation_space"]["spaces"]) == {"image", "state"}
    assert meta["policy_kwargs"]["share_features_extractor"] is False
    load_policy(read_metadata(run))
    assert_evaluates_in_pixel_envs(run, tmp_path / "reports")


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--set", "asymmetric_critic=true"], ["'asymmetric_critic'", "pixels"]),
        ([*PIXELS, "--set", "asymmetric_critic=true", "--vec-env", "dummy"], ["--vec-env batched"]),
    ],
)
def test_an_asymmetric_critic_it_cannot_have_is_one_line(tmp_path, capsys, argv, words):
    assert train.main([*argv, "--run-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(w in err for w in words), err
