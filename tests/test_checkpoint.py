"""Training checkpoints restore a model exactly, and read nothing that could run code."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
from stand_in import sb3_model

from capture_bench.training.common.checkpoint import (
    CheckpointError,
    list_checkpoints,
    read_checkpoint,
    restore,
    save_checkpoint,
)


def _equal(a, b) -> bool:
    """Deep equality of state dicts: tensors exactly, containers entry by entry."""
    import torch

    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    return a == b


def _assert_same_state(a, b) -> None:
    pa, pb = a.get_parameters(), b.get_parameters()
    assert pa.keys() == pb.keys()
    for name in pa:  # the policy and every optimiser's state
        assert _equal(pa[name], pb[name]), name
    for name in ("num_timesteps", "_n_updates", "_episode_num"):
        assert getattr(a, name) == getattr(b, name)


@pytest.mark.parametrize(("algorithm", "normalize"), [("PPO", True), ("SAC", True), ("TD3", False)])
def test_a_restored_model_equals_the_saved_one(algorithm, normalize, tmp_path):
    trained, venv = sb3_model(algorithm, normalize=normalize, learn=96)
    off_policy = algorithm != "PPO"
    path = save_checkpoint(trained, tmp_path, replay_buffer=off_policy)
    assert path.name == "step_96" and list_checkpoints(tmp_path) == [(96, path)]
    fresh, fresh_venv = sb3_model(algorithm, normalize=normalize, learn=0)
    restore(fresh, read_checkpoint(path))
    _assert_same_state(trained, fresh)
    if algorithm == "SAC":
        assert float(fresh.log_ent_coef.detach()) == float(trained.log_ent_coef.detach())
    if off_policy:
        for name in ("observations", "actions", "rewards", "dones"):
            np.testing.assert_array_equal(
                getattr(fresh.replay_buffer, name), getattr(trained.replay_buffer, name)
            )
        assert (fresh.replay_buffer.pos, fresh.replay_buffer.full) == (
            trained.replay_buffer.pos,
            trained.replay_buffer.full,
        )
    if normalize:
        np.testing.assert_array_equal(fresh_venv.obs_rms.mean, venv.obs_rms.mean)
        np.testing.assert_array_equal(fresh_venv.ret_rms.var, venv.ret_rms.var)
        assert fresh_venv.obs_rms.count == venv.obs_rms.count
    obs = np.random.default_rng(0).uniform(-3, 3, (20, 16)).astype(np.float32)
    np.testing.assert_array_equal(
        fresh.predict(obs, deterministic=True)[0], trained.predict(obs, deterministic=True)[0]
    )
    fresh.learn(32, reset_num_timesteps=False)  # and it trains on
    assert fresh.num_timesteps == 96 + 32


class _Payload:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
def test_hostile_files_are_refused_and_run_nothing(tmp_path):
    trained, _ = sb3_model("SAC", learn=32)
    path = save_checkpoint(trained, tmp_path / "c", replay_buffer=True)
    marker = tmp_path / "ran"
    (path / "parameters.pt").write_bytes(pickle.dumps({"state_dicts": _Payload(marker)}))
    with pytest.raises(CheckpointError, match="parameters.pt: unreadable parameters"):
        read_checkpoint(path)
    path = save_checkpoint(trained, tmp_path / "d", replay_buffer=True)
    np.savez(path / "replay_buffer.npz", observations=np.array([_Payload(marker)], dtype=object))
    with pytest.raises(CheckpointError, match="replay_buffer.npz: unreadable replay buffer"):
        read_checkpoint(path)
    assert not marker.exists()


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ("not json", "unreadable checkpoint state"),
        ({"format": "pickle"}, "key 'format'"),
        ({"counters": {"num_timesteps": -1}}, "key 'counters'"),
        ({"vecnormalize": {"obs_rms": 1}}, "key 'vecnormalize'"),
    ],
)
def test_a_broken_state_file_is_one_clear_error(change, expected, tmp_path):
    trained, _ = sb3_model("PPO", learn=32)
    path = save_checkpoint(trained, tmp_path, replay_buffer=False)
    state = json.loads((path / "state.json").read_text())
    text = change if isinstance(change, str) else json.dumps(state | change)
    (path / "state.json").write_text(text)
    with pytest.raises(CheckpointError, match=expected) as caught:
        read_checkpoint(path)
    assert "state.json" in str(caught.value) and "\n" not in str(caught.value)


def test_a_checkpoint_of_another_model_does_not_restore(tmp_path):
    trained, _ = sb3_model("PPO", learn=32)
    path = save_checkpoint(trained, tmp_path, replay_buffer=False)
    other, _ = sb3_model("SAC")
    with pytest.raises(CheckpointError, match="a PPO checkpoint, but the run trains SAC"):
        restore(other, read_checkpoint(path))
    normalized, _ = sb3_model("PPO", normalize=True)
    with pytest.raises(CheckpointError, match="VecNormalize"):
        restore(normalized, read_checkpoint(path))
