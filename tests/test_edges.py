"""The edges of the envs and the commands: arguments an env cannot honour are refused when it is
made (``image_size`` without pixels, ``render_mode="human"`` without a display), and Ctrl-C or
SIGTERM at any moment of a command, its imports and its report's replacement included, ends it
with one line on stderr that tells the truth about what is on disk, and 130 or 143."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import pytest
from processes import default_sigint

from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv

ROOT = Path(__file__).parents[1]


# -- image_size applies only to the pixel observation ---------------------------------------------


@pytest.mark.parametrize(
    "make",
    [
        lambda: gym.make("CaptureBench/Paper-v1", image_size=(64, 64)),
        lambda: gym.make_vec("CaptureBench/Paper-v1", 2, image_size=(64, 64)),
        lambda: gym.make_vec(
            "CaptureBench/Paper-v1", 2, vectorization_mode="sync", image_size=(64, 64)
        ),
        lambda: CaptureEnv("paper", observation_source="truth", image_size=(84, 84)),
        lambda: CaptureVectorEnv(2, "paper", observation_source="ekf", image_size=(84, 84)),
    ],
    ids=["make", "make_vec", "make_vec-sync", "CaptureEnv", "CaptureVectorEnv"],
)
def test_an_image_size_without_pixels_is_refused(make):
    with pytest.raises(ValueError, match=r'image_size=\(\d+, \d+\) applies only with '
                       r'observation_source="pixels"'):  # fmt: skip
        make()


def test_the_image_size_default_and_the_pixels_size_still_work():
    with gym.make("CaptureBench/Paper-v1") as env:
        assert env.observation_space.shape == (16,)
    with CaptureEnv("paper", image_size=None) as env:
        assert env.task.image_size == (84, 84)
    with gym.make("CaptureBench/Paper-v1", observation_source="pixels", image_size=(64, 48)) as env:
        assert env.observation_space["image"].shape == (3, 48, 64)
    venv = CaptureVectorEnv(2, "paper", observation_source="pixels")
    assert venv.single_observation_space["image"].shape == (3, 84, 84)
    venv.close()


def test_training_makes_its_envs_without_an_image_size_unless_it_observes_pixels():
    from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv
    from capture_bench.training.config.hyperparameters import image_size

    assert image_size({}) is None and image_size({"image_size": 64}) == (64, 64)
    venv = CaptureSB3VecEnv(2, "paper")  # a mixture's envs are made so
    venv.close()


# -- render_mode="human" needs a display -----------------------------------------------------------


@pytest.mark.skipif(sys.platform == "darwin" or os.name != "posix", reason="X11 platforms only")
def test_human_rendering_without_a_display_is_refused_when_the_env_is_made(monkeypatch):
    """Before, ``reset()`` ended the process with status 1 and printed nothing (pybullet's GUI
    connection fails hard). Nothing here opens a window: with no DISPLAY there is none to open,
    and with one the env is made and closed without a reset (the window opens at reset)."""
    monkeypatch.delenv("DISPLAY", raising=False)
    for make in (
        lambda: gym.make("CaptureBench/Paper-v1", render_mode="human"),
        lambda: CaptureEnv("paper", render_mode="human"),
    ):
        with pytest.raises(ValueError, match="DISPLAY is not set") as raised:
            make()
        assert 'render_mode="rgb_array"' in str(raised.value)
    monkeypatch.setenv("DISPLAY", ":99")
    CaptureEnv("paper", render_mode="human").close()  # made and closed: no window
    monkeypatch.delenv("DISPLAY")
    CaptureEnv("paper", render_mode="rgb_array").close()


# -- Ctrl-C and SIGTERM while a command's modules import -----------------------------------------

#: Runs a root script (``path``) or ``python -m`` (``module``) as Python would, after a finder
#: that sends this process a signal as the module ``target`` is about to be imported: the signal
#: lands in the middle of the imports, every time.
SIGNAL_ON_IMPORT = """
import os, runpy, sys
target, signum, how, *argv = sys.argv[1:]

class SignalOnImport:
    def find_spec(self, name, path=None, module=None):
        if name == target:
            sys.meta_path.remove(self)
            os.kill(os.getpid(), int(signum))
        return None

sys.meta_path.insert(0, SignalOnImport())
sys.argv = argv
if how == "module":
    runpy.run_module(argv[0], run_name="__main__", alter_sys=True)
else:
    runpy.run_path(argv[0], run_name="__main__")
"""

COMMANDS = {
    "evaluate.py": ("capture_bench", "path", ["evaluate.py", "--suite", "quick"]),
    "evaluate.py (cli)": (
        "capture_bench.evaluation.cli", "path", ["evaluate.py", "--suite", "quick"]
    ),
    "train.py": ("capture_bench.training.common.run", "path", ["train.py", "--algo", "ppo"]),
    "tune.py": ("capture_bench", "path", ["tune.py", "--algo", "sac"]),
    "python -m capture_bench": (
        "capture_bench.evaluation.cli", "module", ["capture_bench", "evaluate", "--suite", "quick"]
    ),
}  # fmt: skip


@pytest.mark.parametrize(("signum", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_signal_while_the_command_imports_is_one_line(command, signum, status, tmp_path):
    target, how, argv = COMMANDS[command]
    done = subprocess.run(
        [sys.executable, "-c", SIGNAL_ON_IMPORT, target, str(int(signum)), how, *argv],
        cwd=ROOT, capture_output=True, text=True, timeout=120, preexec_fn=default_sigint,
    )  # fmt: skip
    prog = command.split(" (")[0]
    assert done.returncode == status, done.stderr
    assert done.stderr == f"{prog}: interrupted while starting; nothing written\n"


@pytest.mark.parametrize(("signum", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_in_the_first_moments_of_evaluate_is_one_line(signum, status, tmp_path):
    """A real ``python evaluate.py``, signalled once its first capture_bench module has imported
    (as ``-X importtime`` reports): the signal lands during the imports or just after, and either
    way the command ends with one line and the signal's status, writing nothing."""
    out = tmp_path / "reports"
    proc = subprocess.Popen(
        [sys.executable, "-X", "importtime", "evaluate.py", "--suite", "quick", "--workers", "1",
         "--out", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=default_sigint,
    )  # fmt: skip
    assert proc.stderr is not None
    seen: list[str] = []
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        seen.append(line)
        if not line or line.split("|")[-1].strip().startswith("capture_bench."):
            break
    proc.send_signal(signum)
    _, rest = proc.communicate(timeout=60)
    said = [
        line for line in [*seen, *rest.splitlines(keepends=True)]
        if line.strip() and not line.startswith("import time:")
    ]  # fmt: skip
    assert proc.returncode == status, said
    assert "Traceback" not in "".join(said)
    assert [line for line in said if "interrupted" in line] == said[-1:], said
    assert said[-1].startswith("evaluate.py: interrupted"), said
    assert not out.exists() or not any(out.iterdir())


# -- a signal as the report is written ------------------------------------------------------------

TINY = ["--suite", "quick", "--agents", "hold", "--scenarios", "paper", "--episodes", "1"]


@pytest.fixture(scope="module")
def report_name(tmp_path_factory) -> str:
    """The folder name of the tiny selection's report."""
    from capture_bench.evaluation.cli import main

    out = tmp_path_factory.mktemp("first")
    assert main([*TINY, "--workers", "1", "--out", str(out)]) == 0
    (folder,) = out.iterdir()
    return folder.name


def _signal_after(call, signum: int):
    def signalled(*args, **kwargs):
        result = call(*args, **kwargs)
        os.kill(os.getpid(), signum)
        return result

    return signalled


def _signal_before(call, signum: int):
    def signalled(*args, **kwargs):
        os.kill(os.getpid(), signum)
        return call(*args, **kwargs)

    return signalled


@pytest.mark.parametrize(
    ("when", "signum", "written"),
    [
        ("as the files are written", signal.SIGTERM, False),
        ("after the previous report is moved aside", signal.SIGTERM, True),
        ("after the new report is renamed into place", signal.SIGTERM, True),
        ("after the new report is renamed into place", signal.SIGINT, True),
        ("after write_report returned", signal.SIGTERM, True),
    ],
)
def test_a_signal_as_the_report_is_written_says_what_is_on_disk(
    when, signum, written, report_name, tmp_path, monkeypatch, capsys
):
    """The one line names the report written if the new report is in place, and says that
    nothing was written (the previous report as it was) if not; the files agree. A signal that
    comes while the previous report is replaced lands once the new one is in place."""
    from capture_bench.evaluation import cli
    from capture_bench.evaluation.reporting import report

    out = tmp_path / "reports"
    previous = out / report_name
    previous.mkdir(parents=True)
    (previous / "marker").write_text("the previous report")
    real_replace = os.replace
    if when == "as the files are written":
        monkeypatch.setattr(report, "_write_all", _signal_before(report._write_all, signum))
    elif when == "after write_report returned":
        monkeypatch.setattr(cli, "_print_summary", _signal_before(cli._print_summary, signum))
    else:
        aside = when == "after the previous report is moved aside"  # else: the new one in place
        moved = f".{report_name}.old-" if aside else f".{report_name}.tmp-"

        def replace(src, dst):
            real_replace(src, dst)
            if Path(dst if aside else src).name.startswith(moved):
                os.kill(os.getpid(), signum)

        monkeypatch.setattr(os, "replace", replace)
    status = cli.main([*TINY, "--workers", "1", "--out", str(out)])
    monkeypatch.setattr(os, "replace", real_replace)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "interrupted" in line]
    assert status == 128 + signum, err
    assert "Traceback" not in err and len(lines) == 1, err
    assert sorted(p.name for p in out.iterdir()) == [report_name]  # nothing half-done left
    if written:
        assert lines[0] == f"evaluate.py: interrupted after the report was written to {previous}/"
        assert not (previous / "marker").exists() and (previous / "results.json").is_file()
    else:
        assert lines[0] == (
            "evaluate.py: interrupted; no report written (a previous report is as it was)"
        )
        assert sorted(p.name for p in previous.iterdir()) == ["marker"]
