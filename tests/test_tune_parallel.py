"""tune.py in parallel: two tune.py processes started together share one SQLite study; --workers 2
runs trials at once in worker processes, pruned against the study's other trials; the sampler
draws trial n's parameters from (--seed, n) whichever process runs it; Ctrl-C or kill -9 leave
no worker running and no trial marked running; bad --workers, --ray-address or storage is one
line and exit 2, with nothing written; Ray tasks on a local Ray instance."""

from __future__ import annotations

import contextlib
import csv
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest
from processes import default_sigint, descendants, outliving
from test_tune import load, one_line_error, tiny_argv

import tune
from capture_bench.interrupts import Terminated, held_interrupts
from capture_bench.training.tune.command import open_study, parse_args, prepare
from capture_bench.training.tune.options import TuneConfig
from capture_bench.training.tune.sampler import configure
from capture_bench.training.tune.search_spaces import sample
from capture_bench.training.tune.workers import STOP_GRACE_S, WORKER_ATTR, HeldTrial, shares

ROOT = Path(__file__).parents[1]
COMPLETE = optuna.trial.TrialState.COMPLETE


def tune_process(argv: list[str], **kwargs) -> subprocess.Popen:
    """``python tune.py argv`` in a child process, as a terminal would start it."""
    return subprocess.Popen(
        [sys.executable, "tune.py", *argv], cwd=ROOT, text=True, preexec_fn=default_sigint,
        env={**os.environ, "PYTHONUNBUFFERED": "1"}, **kwargs,
    )  # fmt: skip


def workers_of(study: optuna.Study) -> dict[str, list[int]]:
    """The trial numbers each worker (``host:pid``) ran (trials added by hand: none)."""
    ran: dict[str, list[int]] = {}
    for trial in study.trials:
        if WORKER_ATTR in trial.user_attrs:
            ran.setdefault(trial.user_attrs[WORKER_ATTR], []).append(trial.number)
    return ran


def test_two_tune_processes_started_together_share_one_sqlite_study(tmp_path):
    out = tmp_path / "out"
    argv = [*tiny_argv(tmp_path, out), "--trials", "2"]  # the same --output, so the same storage
    first, second = (
        tune_process(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE) for _ in range(2)
    )
    for proc in (first, second):
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
    study = load(out)
    assert sorted(t.number for t in study.trials) == [0, 1, 2, 3]
    assert {t.state for t in study.trials} == {COMPLETE}
    ran = workers_of(study)
    pids = {name.rsplit(":", 1)[1] for name in ran}
    assert pids == {str(first.pid), str(second.pid)}, ran  # two trials from each process
    assert sorted(map(len, ran.values())) == [2, 2]
    params = [tuple(sorted(t.params.items())) for t in study.trials]
    assert len(set(params)) == 4, params  # no two trials sampled the same parameters
    # the outputs written last read the study after both processes' trials had finished
    rows = list(csv.DictReader((out / "trials.csv").open()))
    assert sorted(row["number"] for row in rows) == ["0", "1", "2", "3"]
    assert {row["state"] for row in rows} == {"COMPLETE"}
    assert f"trial {study.best_trial.number}," in (out / "best.yaml").read_text()
    assert sorted(p.name for p in out.iterdir()) == [
        "best.yaml", "optimization_history.png", "param_importances.png", "study.db", "trials.csv"
    ]  # fmt: skip


def test_workers_run_the_trials_at_once_in_their_own_processes(tmp_path):
    out = tmp_path / "out"
    argv = [*tiny_argv(tmp_path, out), "--trials", "3", "--workers", "2"]
    assert tune.main(argv) == 0
    study = load(out)
    assert [t.number for t in study.trials] == [0, 1, 2]
    assert {t.state for t in study.trials} == {COMPLETE}
    ran = workers_of(study)
    assert sorted(map(len, ran.values())) == [1, 2], ran  # shares of 3 trials over 2 workers
    assert not any(name.endswith(f":{os.getpid()}") for name in ran)  # none ran in this process
    firsts = [study.trials[numbers[0]] for numbers in ran.values()]
    assert max(t.datetime_start for t in firsts) < min(t.datetime_complete for t in firsts)
    assert len({tuple(sorted(t.params.items())) for t in study.trials}) == 3
    assert len(list(csv.DictReader((out / "trials.csv").open()))) == 3


def test_workers_prune_against_the_trials_of_other_processes(tmp_path):
    out = tmp_path / "out"
    argv = tiny_argv(tmp_path, out, "--n-startup-trials", "1")
    setup = prepare(*parse_args(argv))
    out.mkdir()
    # a trial of another process that captured everything at both validations: the median
    open_study(setup).add_trial(
        optuna.trial.create_trial(value=1.0, intermediate_values={1: 1.0, 2: 1.0})
    )
    assert tune.main([*argv, "--trials", "2", "--workers", "2"]) == 0
    trials = load(out).trials[1:]
    assert [t.state for t in trials] == [optuna.trial.TrialState.PRUNED] * 2
    assert [set(t.intermediate_values) for t in trials] == [{1}, {1}]  # stopped at the first
    assert len(workers_of(load(out))) == 2


def test_trial_n_draws_the_same_random_parameters_in_any_process():
    """The startup trials are random: trial 3's sample depends on (--seed, 3) alone, not on the
    process, nor on the trials before it, nor on their results."""
    config = TuneConfig(algo="sac", seed=7, n_startup_trials=10)

    def fourth_sample(tell: bool) -> dict:
        study = configure(optuna.create_study(direction="maximize"), config)
        for _ in range(3):
            trial = study.ask()
            sample(trial, "sac", 1000)
            if tell:
                study.tell(trial, 0.5)
        trial = study.ask()
        assert trial.number == 3
        return sample(trial, "sac", 1000)

    assert fourth_sample(tell=True) == fourth_sample(tell=False)
    other = configure(optuna.create_study(direction="maximize"), TuneConfig(algo="sac", seed=8))
    assert sample(other.ask(), "sac", 1000) != sample(
        configure(optuna.create_study(direction="maximize"), config).ask(), "sac", 1000
    )


def test_trials_are_shared_out_over_the_workers():
    assert shares(3, 2) == [2, 1] and shares(4, 2) == [2, 2] and shares(10, 4) == [3, 3, 2, 2]
    assert shares(2, 5) == [1, 1] and shares(0, 3) == []


def test_bad_workers_ray_address_or_storage_is_one_line_and_writes_nothing(
    capsys, tmp_path, monkeypatch
):
    out = tmp_path / "out"
    base = [*tiny_argv(tmp_path, out), "--trials", "2"]
    cases = [
        (["--workers", "0"], ["--workers must be >= 1, got 0"]),
        (["--workers", "-2"], ["--workers must be >= 1, got -2"]),
        (["--workers", "two"], ["--workers", "two"]),
        (["--ray-address", "127.0.0.1:1"], ["--ray-address 127.0.0.1:1", "no Ray cluster"]),
        (["--ray-address", "ray://127.0.0.1:1"], ["ray://127.0.0.1:1", "no Ray cluster"]),
        (["--ray-address", "nowhere"], ["--ray-address nowhere", "HOST:PORT"]),
        (
            ["--workers", "2", "--storage", "sqlite:///:memory:"],
            ["--storage sqlite:///:memory:", "private to one process"],
        ),
    ]
    for extra, expected in cases:
        one_line_error(capsys, [*base, *extra], *expected)
        assert not out.exists(), extra
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    one_line_error(capsys, [*base, "--ray-address", "auto"], "--ray-address needs Ray", "pip")
    assert not out.exists()


def _running_trials(database: Path) -> int:
    try:
        with contextlib.closing(sqlite3.connect(database)) as connection:
            query = "SELECT COUNT(*) FROM trials WHERE state = 'RUNNING'"
            return connection.execute(query).fetchone()[0]
    except sqlite3.Error:  # not created yet
        return 0


@pytest.mark.parametrize(("signum", "status"), [(signal.SIGINT, 130), (signal.SIGKILL, -9)])
def test_a_signal_leaves_no_worker_and_no_running_trial(signum, status, tmp_path):
    """Ctrl-C in a terminal (SIGINT to the whole process group): tune.py stops its workers, which
    record their trials as failed; kill -9 of tune.py alone: the workers find it gone and do the
    same by themselves."""
    out = tmp_path / "out"
    argv = [*tiny_argv(tmp_path, out), "--trials", "4", "--workers", "2"]
    argv[argv.index("32")] = "100000"  # trials that are still running when the signal comes
    proc = tune_process(
        argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and _running_trials(out / "study.db") < 2:
            time.sleep(0.2)
        assert _running_trials(out / "study.db") == 2, "the workers never started a trial"
        started = descendants(proc.pid)  # the workers, the forkserver, the resource tracker
        if signum == signal.SIGINT:
            os.killpg(proc.pid, signum)  # its own session: tune.py and every process it started
        else:
            proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == status, err
        # within a worker's grace to record its trial, twice
        assert not outliving(started, 2 * STOP_GRACE_S), "a process outlived tune.py"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # its own session: whatever of it is left
    states = [t.state.name for t in load(out).trials]
    assert states == ["FAIL", "FAIL"], (states, err)
    if signum == signal.SIGINT:
        assert "interrupted" in err and "Traceback" not in err
        assert len(list(csv.DictReader((out / "trials.csv").open()))) == 2


@pytest.fixture
def local_ray():
    """A new Ray instance of two CPUs on the loopback, shut down after the test."""
    ray = pytest.importorskip("ray")
    from capture_bench.ray_cluster import start_local_ray

    start_local_ray(num_cpus=2, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def test_ray_tasks_run_the_trials_in_one_study(tmp_path, local_ray):
    out = tmp_path / "out"
    argv = [*tiny_argv(tmp_path, out), "--trials", "2", "--workers", "2"]
    assert tune.main([*argv, "--ray-address", "local"]) == 0  # the Ray initialised here
    study = load(out)
    assert [t.state for t in study.trials] == [COMPLETE, COMPLETE]
    assert len(workers_of(study)) == 2  # one trial in each task
    assert len(list(csv.DictReader((out / "trials.csv").open()))) == 2


def test_an_interrupt_outside_training_is_held_until_training_starts():
    """What keeps a trial from being left marked running: a signal that comes while Optuna
    records a trial is raised only where training is (inside ``raising()``)."""
    before = signal.getsignal(signal.SIGTERM)
    with held_interrupts((signal.SIGTERM,)) as held:
        os.kill(os.getpid(), signal.SIGTERM)  # handled here, between bytecodes: held
        assert isinstance(held.pending, Terminated)
        with pytest.raises(Terminated), held.raising():
            pass
    with held_interrupts((signal.SIGTERM,)) as held:
        with pytest.raises(Terminated), held.raising():
            os.kill(os.getpid(), signal.SIGTERM)  # raised at once
            time.sleep(5)
    assert signal.getsignal(signal.SIGTERM) == before  # the previous handler restored


def test_an_interrupt_inside_a_trials_storage_call_lands_once_the_call_is_done():
    """A signal during a trial's write to its study (inside ``raising()``) waits for the write to
    finish, and is raised as it returns: a write cut in half would leave its SQLite transaction
    open and every other writer waiting on its lock."""

    class Trial:
        number = 7

        def __init__(self) -> None:
            self.written: list[tuple[str, int]] = []

        def set_user_attr(self, key: str, value: int) -> None:
            os.kill(os.getpid(), signal.SIGTERM)  # the signal comes inside the write
            self.written.append((key, value))

    inner = Trial()
    with held_interrupts((signal.SIGTERM,)) as held:
        trial = HeldTrial(inner, held)
        assert trial.number == 7
        with pytest.raises(Terminated), held.raising():
            trial.set_user_attr("a", 1)
            pytest.fail("the held interrupt was not raised as the write returned")
        assert inner.written == [("a", 1)]
        trial.set_user_attr("b", 2)  # outside training: held, not raised
        assert inner.written == [("a", 1), ("b", 2)] and held.pending is not None
