"""Limits that keep train.py and the model loaders within the machine: hyper-parameters that size
memory are bounded and estimated before anything is built; model files are size-checked before
anything reads them; one train.py per run directory. Each refusal is one line with exit status 2
and nothing written."""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from stand_in import TINY_PPO

import train
from capture_bench.training.common import run as train_run

ROOT = Path(__file__).parents[1]
MODEL = ROOT / "models" / "dagger-dls-paper"
TINY = TINY_PPO


def one_line_error(capsys, argv: list[str], *expected: str) -> str:
    assert train.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("train.py: error: "), err
    for text in expected:
        assert text in err, err
    return err


def _snapshot(directory: Path) -> dict[str, bytes]:
    return {str(p): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def _no_training(monkeypatch) -> None:
    """Make a run that gets past the checks fail at once instead of training for minutes."""

    def refuse(*args, **kwargs):
        raise AssertionError("training started: the input was not refused before any work")

    monkeypatch.setattr(train_run, "train", refuse)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny PPO config (a file)."""
    path = tmp_path_factory.mktemp("limits") / "tiny.yaml"
    path.write_text(TINY)
    return path


@pytest.fixture(scope="module")
def finished(tiny: Path) -> Path:
    """A finished 64-step PPO run with checkpoints at 32 and 64 steps (tests copy it)."""
    run_dir = tiny.parent / "run"
    assert train.main(["--config", str(tiny), "--run-dir", str(run_dir)]) == 0
    return run_dir


def _copy(run: Path, tmp_path: Path) -> Path:
    shutil.copytree(run, tmp_path / "run")
    return tmp_path / "run"


# --------------------------------------------------------------------------- hyper-parameters


def test_a_rollout_no_machine_holds_is_refused_by_its_key_then_the_same_directory_trains(
    tmp_path, tiny, capsys
):
    run_dir = tmp_path / "run"
    one_line_error(
        capsys,
        ["--set", "n_steps=1000000000000", "--run-dir", str(run_dir)],
        "key 'n_steps'",
        "1000000000000",
        "[2, 524288]",
    )
    assert not run_dir.exists()  # no config.json left to block a new run or a resume
    assert train.main(["--config", str(tiny), "--run-dir", str(run_dir)]) == 0
    assert (run_dir / "metadata.json").is_file()


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--algo", "sac", "--set", "buffer_size=1000000000"], ("'buffer_size'", "1e+08")),
        (["--set", "batch_size=100000000"], ("'batch_size'", "524288")),
        (["--set", "n_envs=1000000"], ("'n_envs'", "65536")),
        (["--set", "policy_kwargs.net_arch=[64, 1000000]"], ("net_arch", "65536")),
        (["--set", f"policy_kwargs.net_arch={[8] * 65}"], ("net_arch", "at most 64 layer")),
        (["--algo", "tqc", "--set", "policy_kwargs.n_quantiles=100000"], ("n_quantiles", "1000")),
        (["--algo", "sac", "--set", "policy_kwargs.n_critics=100000"], ("n_critics", "1000")),
        (
            ["--set", "imitate=incremental_ik", "--set", "imitation_steps=10000000000"],
            ("'imitation_steps'", "1e+08"),
        ),
        (["--total-timesteps", str(2**60)], ("--total-timesteps", "at most 9007199254740992")),
    ],
)
def test_each_key_that_sizes_memory_is_bounded(tmp_path, capsys, monkeypatch, argv, expected):
    _no_training(monkeypatch)
    run_dir = tmp_path / "run"
    one_line_error(capsys, [*argv, "--run-dir", str(run_dir)], *expected)
    assert not run_dir.exists()


@pytest.mark.parametrize(
    ("argv", "available", "expected"),
    [
        (
            ["--set", "n_steps=524288", "--n-envs", "16"],
            2**30,
            ("n_steps 524288 x n_envs 16", "the rollout buffer", "819 MiB", "80% of the 1.0 GiB"),
        ),
        (
            ["--algo", "sac", "--set", "buffer_size=100000000"],
            4 * 2**30,
            ("buffer_size 100000000", "the replay buffer", "3.2 GiB"),
        ),
        (
            ["--set", "policy_kwargs.net_arch=[8192, 8192, 8192]"],
            2**30,
            ("policy_kwargs.net_arch [8192, 8192, 8192]", "the networks"),
        ),
        (
            ["--set", "imitate=incremental_ik", "--set", "imitation_rounds=1000"],
            2**30,
            ("imitation_rounds 1000 x imitation_steps 200000", "the imitation's data set"),
        ),
    ],
)
def test_a_run_beyond_the_memory_available_is_refused_before_anything_is_built(
    tmp_path, tiny, capsys, monkeypatch, argv, available, expected
):
    monkeypatch.setattr(train_run, "_available_memory", lambda: available)
    _no_training(monkeypatch)
    run_dir = tmp_path / "run"
    one_line_error(capsys, [*argv, "--run-dir", str(run_dir)], *expected)
    assert not run_dir.exists()
    # a small run fits the same machine, in the same directory
    monkeypatch.setattr(train_run, "_available_memory", lambda: 256 * 2**20)
    monkeypatch.setattr(train_run, "train", lambda *args: 0)
    assert train.main(["--config", str(tiny), "--run-dir", str(run_dir)]) == 0


def test_a_resume_beyond_the_memory_available_is_refused_and_changes_nothing(
    finished, tmp_path, capsys, monkeypatch
):
    run_dir = _copy(finished, tmp_path)
    before = _snapshot(run_dir)
    monkeypatch.setattr(train_run, "_available_memory", lambda: 2**20)
    _no_training(monkeypatch)
    one_line_error(
        capsys, ["--resume", str(run_dir), "--total-timesteps", "128"], "80% of the 1.0 MiB"
    )
    assert _snapshot(run_dir) == before


def test_the_estimate_bounds_what_sb3_allocates_and_the_shipped_configs_fit_a_laptop():
    import numpy as np
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer

    from capture_bench.agents.features import EXTRA_SIZE
    from capture_bench.task.observation import observation_space
    from capture_bench.task.scenarios import load_scenario
    from capture_bench.training.config.hyperparameters import (
        ACTION_SIZE,
        ALGORITHMS,
        EXTRA_FEATURES,
        memory_estimate,
        resolve_hyperparameters,
    )

    assert EXTRA_FEATURES == EXTRA_SIZE
    obs, act = observation_space(), spaces.Box(-1.0, 1.0, (ACTION_SIZE,), np.float32)

    def held(buffer) -> int:
        return sum(v.nbytes for v in vars(buffer).values() if isinstance(v, np.ndarray))

    rollout = RolloutBuffer(256, obs, act, n_envs=8)
    rollout.reset()
    parts = memory_estimate("ppo", {"n_envs": 8, "n_steps": 256, "policy_kwargs": {}}, False)
    estimate = dict((what, size) for _, what, size in parts)["the rollout buffer"]
    assert held(rollout) <= estimate <= 4 * held(rollout)

    replay = ReplayBuffer(4000, obs, act, n_envs=4)
    parts = memory_estimate("sac", {"n_envs": 4, "buffer_size": 4000, "policy_kwargs": {}}, False)
    estimate = dict((what, size) for _, what, size in parts)["the replay buffer"]
    assert held(replay) <= estimate <= 2 * held(replay)

    # The imitation's data set: float32 rows of the estimate; with pixels the images kept as uint8
    # (one byte a number, 84 x 84 x 3 of the default image), the state as float32; three copies.
    hp = {"n_envs": 8, "policy_kwargs": {}, "imitate": "dls", "imitation_rounds": 2}
    for pixels, row in [(False, 4 * (16 + 6)), (True, 84 * 84 * 3 + 4 * (7 + 6))]:
        parts = memory_estimate("ppo", {**hp, "imitation_steps": 800}, pixels)
        estimate = dict((what, size) for _, what, size in parts)["the imitation's data set"]
        assert estimate == 3 * 1600 * row, (pixels, estimate)

    for algo in ALGORITHMS:  # the shipped configs are refused on no machine of 4 GiB
        hp, _, _ = resolve_hyperparameters(algo, load_scenario("paper"))
        needed = sum(size for *_, size in memory_estimate(algo, hp, False))
        assert needed + hp["n_envs"] * train_run.BATCHED_ENV_MEMORY_BYTES < 0.8 * 4 * 2**30, algo


@pytest.mark.parametrize(
    ("error", "status"), [(MemoryError, 2), (KeyboardInterrupt, 130), (RuntimeError, None)]
)
def test_a_new_run_that_fails_before_its_first_checkpoint_leaves_nothing(
    tmp_path, tiny, capsys, monkeypatch, error, status
):
    """SB3 allocates its buffers in the model's constructor: a failure there (or an interrupt
    while the envs start) leaves no config.json that would block the same command."""
    run_dir = tmp_path / "run"
    argv = ["--config", str(tiny), "--run-dir", str(run_dir)]

    def fail(*args, **kwargs):
        raise error()

    with monkeypatch.context() as patch:
        patch.setattr(train_run, "build_model", fail)
        if status is None:
            with pytest.raises(error):
                train.main(argv)
        else:
            assert train.main(argv) == status
    err = capsys.readouterr().err
    if error is MemoryError:
        assert len(err.strip().splitlines()) == 1 and "out of memory" in err, err
    assert not run_dir.exists()
    assert train.main(argv) == 0  # the same command, again


def test_a_failed_new_run_in_a_folder_of_the_users_keeps_the_users_files(
    tmp_path, tiny, monkeypatch
):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "notes.txt").write_text("mine")

    def fail(*args, **kwargs):
        raise MemoryError()

    monkeypatch.setattr(train_run, "build_model", fail)
    assert train.main(["--config", str(tiny), "--run-dir", str(run_dir)]) == 2
    assert sorted(p.name for p in run_dir.iterdir()) == ["notes.txt"]


# --------------------------------------------------------------------------- model files


def _forged_zip(path: Path, name: str, declared: int) -> Path:
    """A 1 kB zip whose one member ``name`` declares ``declared`` bytes (< 4 GiB) in its headers."""
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr(name, b"x" * 1024)
    data = bytearray(path.read_bytes())
    for signature, offset in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):  # local, central
        at = data.index(signature) + offset
        data[at : at + 4] = declared.to_bytes(4, "little")
    path.write_bytes(bytes(data))
    return path


def _deflated_zeros(path: Path, name: str, mib: int) -> Path:
    """A zip of ``mib`` MiB of zeros, deflated (~1000:1: a zip bomb), written in 1 MiB chunks."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        with archive.open(name, "w", force_zip64=True) as member:
            chunk = bytes(2**20)
            for _ in range(mib):
                member.write(chunk)
    return path


def _record_torch_load(monkeypatch) -> list:
    import torch

    calls: list = []

    def record(*args, **kwargs):
        calls.append(args)
        raise RuntimeError("torch.load was called")

    monkeypatch.setattr(torch, "load", record)
    return calls


def _one_line(message: str) -> None:
    assert "\n" not in message and len(message) < 400, message


@pytest.mark.parametrize(
    ("bomb", "expected"),
    [
        ("declared", ("declares 3072 MiB uncompressed", "512 MiB")),
        ("deflated", ("declares 64 MiB uncompressed", "compression ratio above the 100")),
    ],
)
def test_a_zip_bomb_policy_pt_is_refused_before_torch_reads_it(
    tmp_path, monkeypatch, bomb, expected
):
    from capture_bench.agents.sb3_policy import PolicyLoadError, load_policy, read_metadata

    directory = tmp_path / "m"
    shutil.copytree(MODEL, directory)
    weights = directory / "policy.pt"
    if bomb == "declared":
        _forged_zip(weights, "policy/data/0", 3 * 2**30)
    else:
        _deflated_zeros(weights, "policy/data/0", 64)
    calls = _record_torch_load(monkeypatch)
    with pytest.raises(PolicyLoadError) as raised:
        load_policy(read_metadata(directory))
    message = str(raised.value)
    _one_line(message)
    assert message.startswith(f"{weights}: ") and all(text in message for text in expected)
    assert calls == []  # nothing was decompressed or allocated


def test_a_policy_pt_larger_than_the_limit_on_disk_is_refused(tmp_path, monkeypatch):
    from capture_bench.agents import policy_file
    from capture_bench.agents.sb3_policy import PolicyLoadError, load_policy, read_metadata

    directory = tmp_path / "m"
    shutil.copytree(MODEL, directory)
    monkeypatch.setattr(policy_file, "MAX_MODEL_FILE_BYTES", 2**20)  # a 1 MiB limit, as an example
    with open(directory / "policy.pt", "ab") as handle:
        handle.truncate(2**20 + 1)
    calls = _record_torch_load(monkeypatch)
    with pytest.raises(PolicyLoadError, match="on disk, more than the 1 MiB a model file may hold"):
        load_policy(read_metadata(directory))
    assert calls == []


def test_an_sb3_zip_bomb_is_refused_before_sb3_reads_it(tmp_path, monkeypatch):
    import stable_baselines3

    from capture_bench.agents.sb3_policy import PolicyLoadError, load_policy, read_metadata

    directory = tmp_path / "m"
    directory.mkdir()
    (directory / "metadata.json").write_text(json.dumps({"algorithm": "PPO"}))
    _forged_zip(directory / "model.zip", "data", 3 * 2**30)
    loads: list = []
    monkeypatch.setattr(stable_baselines3.PPO, "load", lambda *a, **k: loads.append(a))
    with pytest.raises(PolicyLoadError) as raised:
        load_policy(read_metadata(directory), trust_model=True)
    message = str(raised.value)
    _one_line(message)
    assert message.startswith(f"{directory / 'model.zip'}: ") and "512 MiB" in message
    assert loads == []


def test_a_metadata_file_beyond_its_limit_is_refused_before_it_is_read(tmp_path):
    from capture_bench.agents.sb3_policy import PolicyLoadError, read_metadata

    directory = tmp_path / "m"
    shutil.copytree(MODEL, directory)
    with open(directory / "metadata.json", "ab") as handle:
        handle.write(b" " * (16 * 2**20))
    with pytest.raises(PolicyLoadError, match="more than the 16 MiB a metadata file may hold"):
        read_metadata(directory)


@pytest.mark.parametrize("file", ["parameters.pt", "replay_buffer.npz"])
def test_a_zip_bomb_checkpoint_is_refused_before_it_is_read(tmp_path, monkeypatch, file):
    import numpy as np
    from stand_in import sb3_model

    from capture_bench.training.common.checkpoint import (
        CheckpointError,
        read_checkpoint,
        save_checkpoint,
    )

    model, _ = sb3_model("SAC")
    step = save_checkpoint(model, tmp_path, replay_buffer=True)
    _deflated_zeros(step / file, "observations.npy", 64)
    calls = _record_torch_load(monkeypatch) if file == "parameters.pt" else []
    original = np.load
    monkeypatch.setattr(np, "load", lambda *a, **k: calls.append(a) or original(*a, **k))
    with pytest.raises(CheckpointError) as raised:
        read_checkpoint(step)
    message = str(raised.value)
    _one_line(message)
    assert message.startswith(f"{step / file}: ") and "compression ratio" in message
    assert calls == []


def test_a_resume_from_a_zip_bomb_checkpoint_is_one_line(finished, tmp_path, capsys, monkeypatch):
    run_dir = _copy(finished, tmp_path)
    _deflated_zeros(run_dir / "checkpoints" / "step_64" / "parameters.pt", "archive/data/0", 64)
    calls = _record_torch_load(monkeypatch)
    before = _snapshot(run_dir)
    one_line_error(
        capsys,
        ["--resume", str(run_dir), "--total-timesteps", "128"],
        "step_64/parameters.pt",
        "compression ratio",
    )
    assert calls == [] and _snapshot(run_dir) == before


# --------------------------------------------------------------------------- one train.py per run


def _hold(directory: Path) -> int:
    """Lock ``directory`` as a running train.py does; returns the descriptor (close to release)."""
    fd = os.open(directory, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd


def test_a_resume_of_a_run_in_use_is_refused_and_changes_nothing(finished, tmp_path, capsys):
    run_dir = _copy(finished, tmp_path)
    before = _snapshot(run_dir)
    fd = _hold(run_dir)
    try:
        err = one_line_error(
            capsys,
            ["--resume", str(run_dir), "--total-timesteps", "128"],
            f"{run_dir}: in use by another train.py (pid {os.getpid()})",
        )
        assert f"--resume {run_dir}" in err
        assert _snapshot(run_dir) == before
    finally:
        os.close(fd)
    assert train.main(["--resume", str(run_dir), "--total-timesteps", "128"]) == 0


def test_a_new_run_into_a_directory_in_use_is_refused_and_writes_nothing(tmp_path, tiny, capsys):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    fd = _hold(run_dir)
    try:
        one_line_error(
            capsys, ["--config", str(tiny), "--run-dir", str(run_dir)], "in use by another"
        )
        assert list(run_dir.iterdir()) == []
    finally:
        os.close(fd)


def test_two_train_processes_on_one_run_and_the_lock_outlives_no_crash(tmp_path, tiny, capsys):
    """A real second train.py: refused, for a new run and a resume, while the first runs; once
    the first is killed (SIGKILL: no handler runs), the run resumes."""
    config = tmp_path / "long.yaml"
    config.write_text(tiny.read_text().replace("total_timesteps: 64", "total_timesteps: 10000000"))
    run_dir = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "train.py", "--config", str(config), "--run-dir", str(run_dir),
         "--vec-env", "dummy"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # learning has started
            if line.startswith("TensorBoard:"):
                break
        one_line_error(
            capsys,
            ["--resume", str(run_dir), "--total-timesteps", "1"],
            f"in use by another train.py (pid {proc.pid})",
        )
        one_line_error(
            capsys, ["--config", str(tiny), "--run-dir", str(run_dir)], "already holds a run"
        )
        from capture_bench.training.common.checkpoint import list_checkpoints

        while not list_checkpoints(run_dir / "checkpoints") and proc.poll() is None:
            proc.stdout.readline()
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    done = list_checkpoints(run_dir / "checkpoints")[-1][0]
    assert train.main(["--resume", str(run_dir), "--total-timesteps", str(done + 64)]) == 0
