"""The features a policy may compute from the observation (capture_bench/agents/features.py):
the appended entries decode to the predicted relative vector's direction and distance, the torch
extractor equals the numpy definition, and a policy using it trains through train.py and loads
through the safe format with the actions SB3's own loading gives."""

from __future__ import annotations

import json

import numpy as np
import pytest

import train
from capture_bench.agents.features import (
    FEATURE_EXTRACTORS,
    RelativeLogDistance,
    decode_relative_features,
    relative_features,
)
from capture_bench.task.observation import decode_observation, encode_observation

T_S = 0.05


def _observation(relative: np.ndarray) -> np.ndarray:
    """An observation whose predicted relative vector (eq. 13) is ``relative`` (m)."""
    ee = np.array([0.4, 0.1, 0.3])
    velocity = np.array([0.01, -0.02, 0.005])
    target = ee + relative - velocity * T_S
    return encode_observation(target, velocity, ee, np.zeros(3), T_S, T_S)


@pytest.mark.parametrize("distance", [2e-6, 1e-4, 1e-3, 2.5e-3, 0.05, 0.3, 1.2])
def test_the_appended_entries_decode_to_the_direction_and_the_distance(distance):
    direction = np.array([0.48, -0.6, 0.64])  # unit length
    obs = _observation(distance * direction)
    features = relative_features(obs)
    u, d = decode_relative_features(features)
    relative = decode_observation(obs, T_S).relative_position  # what the observation holds
    np.testing.assert_allclose(u, relative / np.linalg.norm(relative), atol=1e-6)
    assert d == pytest.approx(np.linalg.norm(relative), rel=1e-5)
    assert d == pytest.approx(distance, rel=1e-3, abs=1e-7)  # float32 observation rounding
    assert features[3] == pytest.approx(np.log10(distance / 1e-3) / 3, abs=1e-3)


def test_log_distance_reads_minus_one_zero_one_at_a_micrometre_a_millimetre_a_metre():
    for distance, expected in ((1e-6, -1.0), (1e-3, 0.0), (1.0, 1.0)):
        assert relative_features(_observation(np.array([0.0, 0.0, distance])))[3] == (
            pytest.approx(expected, abs=2e-3)
        )
    zero = relative_features(np.zeros(16, np.float32))  # no estimate yet: X^_T = X_E
    assert np.isfinite(zero).all() and zero[3] == pytest.approx(-1.0)


def test_the_torch_extractor_is_the_observation_then_the_numpy_features():
    import gymnasium
    import torch

    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (64, 16)).astype(np.float32)
    obs[:8, 12:15] *= 1e-3  # millimetres
    extractor = RelativeLogDistance(gymnasium.spaces.Box(-10, 10, (16,), np.float32))
    out = extractor(torch.as_tensor(obs)).numpy()
    assert out.shape == (64, 20) and extractor.features_dim == 20
    np.testing.assert_array_equal(out[:, :16], obs)
    np.testing.assert_allclose(out[:, 16:], relative_features(obs), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match=r"shape \(16,\)"):
        RelativeLogDistance(gymnasium.spaces.Box(-1, 1, (4,), np.float32))
    assert set(FEATURE_EXTRACTORS) == {
        "flatten",
        "relative_log_distance",
        "combined",
        "keypoints",
        "marker_keypoints",
    }
    from capture_bench.training.config.hyperparameters import FEATURES

    assert FEATURES == tuple(FEATURE_EXTRACTORS)  # the config's choices are the extractors


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_a_policy_with_the_features_trains_and_loads_safely_with_sb3s_actions(tmp_path, algo):
    from capture_bench.agents.sb3_policy import load_policy, load_trusted, read_metadata

    tiny = {
        "ppo": ["n_steps=32", "batch_size=32", "n_epochs=1"],
        "sac": ["learning_starts=32", "batch_size=16", "buffer_size=500"],
    }[algo]
    run_dir = tmp_path / "run"
    sets = [*tiny, "policy_kwargs.features_extractor=relative_log_distance"]
    sets += ["policy_kwargs.net_arch=[8]", "total_timesteps=64", "n_envs=2"]
    argv = ["--algo", algo, *(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]
    assert train.main(argv) == 0
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["policy_kwargs"]["features_extractor"] == "relative_log_distance"
    metadata = read_metadata(run_dir)
    safe, trusted = load_policy(metadata), load_trusted(metadata)
    assert isinstance(
        safe.policy.features_extractor if algo == "ppo" else safe.policy.actor.features_extractor,
        RelativeLogDistance,
    )
    rng = np.random.default_rng(1)
    for _ in range(5):
        obs = rng.uniform(-1, 1, 16).astype(np.float32)
        obs[12:15] *= 1e-3
        a, _ = safe.policy.predict(obs, deterministic=True)
        b, _ = trusted.policy.predict(obs, deterministic=True)
        np.testing.assert_array_equal(a, b)


def test_the_features_refuse_normalized_observations(tmp_path, capsys):
    argv = ["--set", "policy_kwargs.features_extractor=relative_log_distance"]
    argv += ["--set", "normalize=true", "--run-dir", str(tmp_path / "r")]
    assert train.main(argv) == 2
    err = capsys.readouterr().err
    assert "normalize: true" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r").exists()
