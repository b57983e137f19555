"""evaluate.py: output folders and the Ray cluster checked first, reports replaced only by what
they are, signals end it at once with no worker left and the previous report intact, and no
worker outlives it however it dies."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from processes import default_sigint, descendants, outliving

from evaluate import main

ROOT = Path(__file__).parents[1]


def one_line_error(capsys, argv: list[str], *expected: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for text in expected:
        assert text in err, err


@pytest.mark.parametrize("option", ["--out", "--episode-plots", "--video"])
def test_an_unwritable_output_folder_is_refused_before_any_episode(option, tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for folder in (blocker, blocker / "below", Path("/proc/capture-bench-report")):
        argv = ["--suite", "quick", "--workers", "1", option, str(folder)]
        if option != "--out":
            argv += ["--out", str(tmp_path / "reports")]
        one_line_error(capsys, argv, option, "writable folder")
    assert not (tmp_path / "reports").exists()


def test_a_read_only_folder_is_refused(tmp_path, capsys):
    if os.geteuid() == 0:
        pytest.skip("root writes through permission bits (the /proc case covers root)")
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    one_line_error(capsys, ["--suite", "quick", "--out", str(folder)], "--out", "cannot write")


def test_a_narrowed_run_never_replaces_the_suites_report(tmp_path, capsys):
    out = tmp_path / "reports"
    (out / "quick").mkdir(parents=True)
    (out / "quick" / "marker").write_text("the quick suite's report")
    argv = ["--suite", "quick", "--agents", "hold", "--scenarios", "paper", "--episodes", "1"]
    assert main([*argv, "--workers", "1", "--out", str(out)]) == 0
    assert (out / "quick" / "marker").read_text() == "the quick suite's report"
    custom = [p for p in out.iterdir() if p.name.startswith("custom-")]
    assert len(custom) == 1 and (custom[0] / "results.json").is_file()
    assert str(custom[0]) in capsys.readouterr().err  # named in the output
    html = (custom[0] / "leaderboard.md").read_text()
    assert "custom selection" in html and "`quick` suite" not in html
    assert main([*argv, "--workers", "1", "--out", str(out)]) == 0  # same selection, same folder
    assert len([p for p in out.iterdir() if p.name.startswith("custom-")]) == 1


def test_a_scenario_file_path_is_accepted(tmp_path, capsys):
    mine = tmp_path / "my_paper.yaml"
    shutil.copy(ROOT / "configs" / "scenarios" / "paper.yaml", mine)
    argv = ["--suite", "quick", "--agents", "hold", "--scenarios", str(mine), "--episodes", "1"]
    assert main([*argv, "--workers", "1", "--out", str(tmp_path / "r")]) == 0
    (report,) = (tmp_path / "r").iterdir()
    assert "my_paper" in (report / "results.csv").read_text()  # named by the file, not its path
    capsys.readouterr()
    bad = tmp_path / "bad.yaml"
    bad.write_text("control:\n  period: -1\n")
    argv[5] = str(bad)
    one_line_error(capsys, [*argv, "--out", str(tmp_path / "r2")], str(bad))
    argv[5] = str(tmp_path / "missing.yaml")
    one_line_error(capsys, [*argv, "--out", str(tmp_path / "r2")], "no such scenario file")
    assert not (tmp_path / "r2").exists()


@pytest.mark.parametrize(("signum", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_ends_evaluate_at_once_with_no_worker_left(signum, status, tmp_path):
    out = tmp_path / "reports"
    (out / "quick").mkdir(parents=True)
    (out / "quick" / "marker").write_text("previous report")
    proc = subprocess.Popen(
        [sys.executable, "evaluate.py", "--suite", "quick", "--episodes", "50", "--workers", "2",
         "--out", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"}, preexec_fn=default_sigint,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    workers: list[int] = []
    while time.monotonic() < deadline and len(workers) < 3:  # forkserver + 2 workers running
        time.sleep(0.2)
        workers = descendants(proc.pid)
    assert len(workers) >= 3, "the workers never started"
    time.sleep(1.0)  # mid-episodes
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == status, err
    assert "Traceback" not in err and "interrupted" in err
    # the forkserver and resource tracker follow within moments
    assert not outliving(workers, 5), "a worker outlived evaluate.py"
    assert (out / "quick" / "marker").read_text() == "previous report"
    assert sorted(p.name for p in out.iterdir()) == ["quick"]  # no staging folder left


def test_an_interrupt_while_the_workers_start_waits_until_each_can_be_killed(monkeypatch):
    """A signal that comes while the pool starts its workers lands once every one is started
    and in the pool's record: then each is killed (one cut off as it started would be missed,
    outlive evaluate.py and fail to read its start-up data)."""
    from concurrent.futures import ProcessPoolExecutor

    from capture_bench.evaluation.running import backends

    started: list = []

    class SignalledPool(ProcessPoolExecutor):
        def submit(self, fn, /, *args, **kwargs):
            os.kill(os.getpid(), signal.SIGINT)  # comes as each worker starts
            future = super().submit(fn, *args, **kwargs)
            started[:] = self._processes.values()
            return future

    monkeypatch.setattr(backends, "ProcessPoolExecutor", SignalledPool)
    with pytest.raises(KeyboardInterrupt):
        backends.map_processes(time.sleep, [30.0, 30.0], workers=2)
    assert len(started) == 2  # both started before the interrupt landed
    # Each ended at once (their sleeps had 30 s to go). Not `exitcode == -SIGKILL`: the pool's
    # manager thread joins the workers beside the kill, and of two threads reading a status from
    # the forkserver one gets end-of-file, which multiprocessing reports as 255.
    assert all(p.exitcode is not None for p in started)
    assert not outliving([p.pid for p in started], 5)


@pytest.mark.parametrize("address", ["127.0.0.1:1", "ray://127.0.0.1:1"])
def test_an_unreachable_ray_cluster_is_refused_in_seconds(tmp_path, address):
    """Ray's own connect retries a dead address for many minutes (its client for 30 s, then a
    traceback); the run is refused first, as bad input (in a child process: a hang must fail
    the test, not stall it)."""
    out = tmp_path / "reports"
    done = subprocess.run(
        [sys.executable, "evaluate.py", "--suite", "quick", "--backend", "ray",
         "--ray-address", address, "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and address in lines[0] and "Traceback" not in lines[0], lines
    assert not out.exists()


def test_no_worker_outlives_evaluate_killed_by_sigkill(tmp_path):
    """SIGKILL leaves evaluate.py no chance to clean up: the workers, the forkserver they fork
    from and multiprocessing's resource tracker must still all end by themselves."""
    proc = subprocess.Popen(
        [sys.executable, "evaluate.py", "--suite", "quick", "--episodes", "50", "--workers", "2",
         "--out", str(tmp_path)],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        started: list[int] = []
        while time.monotonic() < deadline and len(started) < 4:  # tracker, forkserver, 2 workers
            time.sleep(0.2)
            started = descendants(proc.pid)
        assert len(started) >= 4, "the workers never started"
        time.sleep(1.0)  # mid-episodes
        proc.kill()
        proc.wait(timeout=10)
        assert not outliving(started, 5), "a process outlived evaluate.py"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # its own session: whatever of it is left
