"""train.py: signals save a checkpoint; every user mistake is one line and exit 2, found first."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from processes import alive, default_sigint, descendants
from stand_in import TINY_PPO

import train

ROOT = Path(__file__).parents[1]
TINY = TINY_PPO


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 64-step PPO run (module scope; tests copy it before changing it)."""
    root = tmp_path_factory.mktemp("robust")
    (root / "tiny.yaml").write_text(TINY)
    argv = ["--config", str(root / "tiny.yaml"), "--run-dir", str(root / "run")]
    assert train.main(argv) == 0
    return root / "run"


def _copy(run: Path, tmp_path: Path) -> Path:
    shutil.copytree(run, tmp_path / "run")
    return tmp_path / "run"


def one_line_error(capsys, argv: list[str], *expected: str) -> str:
    assert train.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for text in expected:
        assert text in err, err
    return err


def _snapshot(directory: Path) -> dict[str, bytes]:
    return {str(p): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


# --------------------------------------------------------------------------- resume


def test_resume_with_no_more_steps_than_done_is_refused_and_changes_nothing(run, tmp_path, capsys):
    run_dir = _copy(run, tmp_path)
    before = _snapshot(run_dir)
    one_line_error(
        capsys,
        ["--resume", str(run_dir), "--total-timesteps", "32"],
        "--total-timesteps 32 is not more than the 64 steps",
        "above 64",
    )
    # its own total, reached: the message names the run's budget, not a flag never passed
    err = one_line_error(capsys, ["--resume", str(run_dir)], "finished", "done 64 steps")
    assert "its total_timesteps 64" in err and "--total-timesteps 64" not in err
    assert f"--resume {run_dir} --total-timesteps <steps>" in err
    assert _snapshot(run_dir) == before


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("{not json", "unreadable"),
        ('{"config": 1, "hyperparameters": {}}', "expected keys"),
        ('{"config": {"sneaky": 1}, "hyperparameters": {}}', "does not hold train.py's options"),
    ],
)
def test_resume_with_a_broken_config_json_is_one_line(run, tmp_path, capsys, text, expected):
    run_dir = _copy(run, tmp_path)
    (run_dir / "config.json").write_text(text)
    one_line_error(
        capsys, ["--resume", str(run_dir), "--total-timesteps", "128"], "config.json", expected
    )


@pytest.mark.parametrize(
    ("key", "value", "expected"),
    [("algo", "dqn", "config.algo"), ("observation_source", "radar", "observation_source"),
     ("scenario", "mars", "config.scenario")],
)  # fmt: skip
def test_resume_of_a_config_that_no_longer_validates(run, tmp_path, capsys, key, value, expected):
    run_dir = _copy(run, tmp_path)
    data = json.loads((run_dir / "config.json").read_text())
    data["config"][key] = value
    (run_dir / "config.json").write_text(json.dumps(data))
    one_line_error(capsys, ["--resume", str(run_dir), "--total-timesteps", "128"], expected)


@pytest.mark.parametrize("damage", ["truncated", "garbage state"])
def test_resume_from_a_corrupt_newest_checkpoint_names_it(run, tmp_path, capsys, damage):
    run_dir = _copy(run, tmp_path)
    newest = run_dir / "checkpoints" / "step_64"
    if damage == "truncated":
        data = (newest / "parameters.pt").read_bytes()
        (newest / "parameters.pt").write_bytes(data[: len(data) // 2])
    else:
        (newest / "state.json").write_text("garbage")
    before = _snapshot(run_dir)
    one_line_error(capsys, ["--resume", str(run_dir), "--total-timesteps", "128"], "step_64")
    assert _snapshot(run_dir) == before


# --------------------------------------------------------------------------- new runs


def test_unwritable_run_dir_is_refused_before_any_work(tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for run_dir in (blocker / "run", Path("/proc/capture-bench-run")):
        one_line_error(capsys, ["--run-dir", str(run_dir)], "--run-dir", "choose a writable folder")


def test_too_many_envs_is_refused(tmp_path, capsys):
    one_line_error(capsys, ["--n-envs", "100000", "--run-dir", str(tmp_path / "r")], "at most")
    assert not (tmp_path / "r").exists()


def test_cuda_without_cuda_is_refused(tmp_path, capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    one_line_error(capsys, ["--device", "cuda", "--run-dir", str(tmp_path / "r")], "--device cpu")
    assert not (tmp_path / "r").exists()


def _progress_targets(monkeypatch) -> list[int]:
    """The targets train.py gives its progress lines (``steps N/target``)."""
    from capture_bench.training import callbacks

    targets: list[int] = []

    class Recording(callbacks.Progress):
        def __init__(self, config, hp, target, **kwargs):
            targets.append(target)
            super().__init__(config, hp, target, **kwargs)

    monkeypatch.setattr(callbacks, "Progress", Recording)
    return targets


def test_a_budget_that_is_not_whole_rollouts_is_rounded_with_one_note(
    tmp_path, capsys, monkeypatch
):
    targets = _progress_targets(monkeypatch)
    (tmp_path / "tiny.yaml").write_text(TINY)
    argv = ["--config", str(tmp_path / "tiny.yaml"), "--total-timesteps", "40"]
    assert train.main([*argv, "--run-dir", str(tmp_path / "r")]) == 0
    out = capsys.readouterr().out
    assert out.count("rounded up to 64") == 1 and "n_steps x n_envs = 32" in out
    assert ", 64 steps -> " in out and targets == [64]  # the real target, not 40
    assert json.loads((tmp_path / "r" / "metadata.json").read_text())["total_timesteps"] == 64


def test_an_off_policy_budget_is_rounded_to_steps_of_all_envs(tmp_path, capsys, monkeypatch):
    """SB3 steps every env together, ``train_freq`` times between looks at the budget."""
    targets = _progress_targets(monkeypatch)
    argv = ["--algo", "td3", "--total-timesteps", "41", "--run-dir", str(tmp_path / "r")]
    for item in ("n_envs=2", "train_freq=3", "learning_starts=8", "batch_size=8",
                 "buffer_size=100", "gradient_steps=1", "policy_kwargs.net_arch=[16]"):  # fmt: skip
        argv += ["--set", item]
    assert train.main(argv) == 0
    out = capsys.readouterr().out
    assert out.count("rounded up to 42") == 1 and "train_freq x n_envs = 6" in out
    assert targets == [42]
    assert json.loads((tmp_path / "r" / "metadata.json").read_text())["total_timesteps"] == 42


# --------------------------------------------------------------------------- signals


def _start(tmp_path: Path, vec_env: str) -> tuple[subprocess.Popen, Path]:
    config = tmp_path / "long.yaml"
    config.write_text(TINY.replace("total_timesteps: 64", "total_timesteps: 100000").replace(
        "n_envs: 1", "n_envs: 2"))  # fmt: skip
    run_dir = tmp_path / "run"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "train.py", "--config", str(config), "--run-dir", str(run_dir),
         "--vec-env", vec_env],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        preexec_fn=default_sigint,
    )  # fmt: skip
    assert proc.stdout is not None
    for line in proc.stdout:  # wait until learning has started
        if line.startswith("TensorBoard:"):
            break
    time.sleep(2.0)  # some updates
    return proc, run_dir


@pytest.mark.parametrize(("signum", "status", "vec_env"), [
    (signal.SIGTERM, 143, "subproc"), (signal.SIGINT, 130, "dummy"),
])  # fmt: skip
def test_a_signal_saves_a_checkpoint_that_resumes(tmp_path, signum, status, vec_env):
    proc, run_dir = _start(tmp_path, vec_env)
    workers = descendants(proc.pid)
    assert vec_env == "dummy" or len(workers) >= 2, workers
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == status, err
    assert "Traceback" not in err and "interrupted at" in out, (out, err)
    time.sleep(0.5)
    left = [pid for pid in workers if alive(pid)]
    assert not left, f"workers {left} outlived train.py"
    from capture_bench.training.common.checkpoint import list_checkpoints

    (steps, _), *_ = reversed(list_checkpoints(run_dir / "checkpoints"))
    assert steps > 0
    assert train.main(["--resume", str(run_dir), "--total-timesteps", str(steps + 64)]) == 0
    assert json.loads((run_dir / "metadata.json").read_text())["total_timesteps"] >= steps + 64
