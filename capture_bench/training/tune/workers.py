"""Where ``tune.py``'s trials run: in this process, in ``--workers`` local processes, or as Ray
tasks on a cluster (``--ray-address``), every one a client of the same study storage.

A worker opens its own connection to the storage (`
open_storage`), takes the study's sampler and pruner (`sampler`)
and runs its share of ``--trials`` (`shares`) with ``study.optimize``; the storage numbers
the trials, so workers never collide, and each trial records the worker that ran it (user
attribute ``worker``, ``host:pid``). Trials write no files (no run directory, a logger that writes
nothing), so workers share nothing but the storage. Processes rather than Optuna's ``n_jobs``
threads: training is CPU-bound Python, which threads would run one at a time.

Stopping. Ctrl-C or SIGTERM ends a trial the same way wherever it runs: the running trial is
recorded as failed (user attribute ``interrupted``) and no other starts; one that comes while
Optuna creates or records a trial, or while the trial writes to the storage, waits until that is
done (`run_trials`, `HeldTrial`). Local workers
ignore SIGINT (Ctrl-C reaches the whole process group): ``tune.py`` sends each SIGTERM, which a
worker takes as Ctrl-C, waits up to `STOP_GRACE_S` for them (a second Ctrl-C: not at
all), kills the rest and records the trials they left running as failed. A worker whose
``tune.py`` ended without that (``kill -9``) stops the same way by itself and exits within
`STOP_GRACE_S` (`end_with_parent`). Ray tasks are
cancelled, which raises KeyboardInterrupt in them.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import signal
import socket
import sys
import time
from multiprocessing.connection import Connection
from signal import SIGINT, SIGTERM
from typing import TYPE_CHECKING, Any

from capture_bench.interrupts import (
    HeldInterrupts,
    exit_status,
    held_interrupts,
    interrupts_deferred,
    sigterm_as_interrupt,
)
from capture_bench.ray_cluster import import_ray, start_ray
from capture_bench.training.tune.storage import open_storage, shared_url
from capture_bench.worker_processes import (
    end_with_parent,
    process_context,
    single_threaded_children,
)

if TYPE_CHECKING:
    from capture_bench.training.tune.options import Setup

#: Seconds a stopped worker has to record its trial as failed before it is killed.
STOP_GRACE_S = 30.0
#: The user attribute naming the worker that runs a trial (``host:pid``).
WORKER_ATTR = "worker"
#: Modules the forkserver imports once, so that each worker forks with them loaded.
PRELOAD = ("capture_bench.training.tune.trial",)
#: The option that asks for Ray, as its messages name it.
RAY_OPTION = "--ray-address"

Outcome = tuple[KeyboardInterrupt | None, list[str]]


def shares(trials: int, workers: int) -> list[int]:
    """``trials`` split over at most ``workers`` workers, none idle: ``trials // n`` each, the
    first ``trials % n`` one more (``n`` the workers that get a trial)."""
    n = min(trials, workers)
    return [trials // n + (i < trials % n) for i in range(n)]


def run_study(study: Any, setup: Setup) -> Outcome:
    """Run ``setup.config.trials`` trials of ``study`` where the options say; return the Ctrl-C
    or SIGTERM that stopped them (None if none did) and a line for each worker that failed."""
    config = setup.config
    parts = shares(config.trials, config.workers)
    if not parts:
        return None, []
    if config.ray_address is not None:
        return run_ray(study, setup, parts, config.ray_address)
    if len(parts) > 1:
        return run_processes(study, setup, parts)
    return run_trials(study, setup, config.trials), []


def load_study(setup: Setup) -> Any:
    """``setup``'s study, opened afresh (a worker's own connection), with its sampler and pruner."""
    import optuna

    from capture_bench.training.tune.sampler import configure

    study = optuna.load_study(study_name=setup.study_name, storage=open_storage(setup.storage))
    return configure(study, setup.config)


def run_trials(
    study: Any, setup: Setup, n_trials: int, signals: tuple[int, ...] = (SIGINT, SIGTERM)
) -> KeyboardInterrupt | None:
    """Run ``n_trials`` trials of ``study`` in this process; return the interrupt that stopped
    them (None if none did).

    ``signals`` (handled in this, the main, thread) interrupt a trial's training; one that comes
    while Optuna creates or records a trial, or inside one of the trial's methods
    (`HeldTrial`), is held until that is done
    (`held_interrupts`), so no trial is left marked running, and
    then no other trial starts. In a Ray task (``signals`` empty) Ray's cancellation raises
    KeyboardInterrupt wherever the task is.
    """
    from capture_bench.training.tune.trial import run_trial

    interrupts: list[KeyboardInterrupt] = []
    name = f"{socket.gethostname()}:{os.getpid()}"
    with held_interrupts(signals) as held:

        def objective(trial: Any) -> float:
            trial.set_user_attr(WORKER_ATTR, name)
            try:
                with held.raising():
                    return run_trial(HeldTrial(trial, held), setup)
            except KeyboardInterrupt as exc:
                interrupts.append(exc)
                trial.set_user_attr("interrupted", True)
                study.stop()
                return math.nan  # Optuna records the trial as failed, without a traceback

        def stop_if_held(study: Any, trial: Any) -> None:
            if held.pending is not None:
                study.stop()

        try:
            study.optimize(objective, n_trials=n_trials, callbacks=[stop_if_held])
        except KeyboardInterrupt as exc:  # a Ray cancellation in Optuna's own code
            interrupts.append(exc)
    if held.pending is not None and not interrupts:
        interrupts.append(held.pending)
    return interrupts[0] if interrupts else None


class HeldTrial:
    """An Optuna trial whose methods run with the interrupts held (`holding`). Each method reads or
    writes the study's storage; an
    interrupt raised inside a SQLite transaction would leave it open, its lock held, and every
    later write to the study, this worker's recording of the interrupted trial as failed and the
    other workers', waiting on that lock."""

    def __init__(self, trial: Any, held: HeldInterrupts) -> None:
        self._trial = trial
        self._held = held

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._trial, name)
        if not callable(value):
            return value

        @functools.wraps(value)
        def held_call(*args: Any, **kwargs: Any) -> Any:
            with self._held.holding():
                return value(*args, **kwargs)

        return held_call


# ------------------------------------------------------------------------ local worker processes


def run_processes(study: Any, setup: Setup, parts: list[int]) -> Outcome:
    """Run ``parts[i]`` trials in local worker process i, all at once (forked from a server that
    has imported the trainer, one numerical thread each); wait for them all. On Ctrl-C or
    SIGTERM here, stop them (the module's docstring)."""
    context = process_context(PRELOAD)
    # Only this process holds `held`: a worker sees end-of-file on `watched` when it ends.
    watched, held = context.Pipe(duplex=False)
    processes = [
        context.Process(target=_process_main, args=(setup, share, watched), name=f"tune-worker-{i}")
        for i, share in enumerate(parts)
    ]
    interrupt = None
    try:
        # An interrupt waits until every worker has started: one cut off as it started would
        # have no pid here to stop it by.
        with interrupts_deferred(), single_threaded_children():
            for process in processes:
                process.start()
        for process in processes:
            process.join()
    except KeyboardInterrupt as exc:
        interrupt = exc
        _stop(processes)
    finally:
        for process in processes:  # an error here, or a worker that outlived its grace
            if process.is_alive():
                process.kill()
                process.join()
        held.close()
        watched.close()
    hosts = {f"{socket.gethostname()}:{p.pid}" for p in processes if p.pid is not None}
    _fail_abandoned(study, hosts)
    failures = [
        f"worker {p.name} (pid {p.pid}) ended with status {p.exitcode}; see its messages above"
        for p in processes
        if interrupt is None and p.exitcode not in (0, None)
    ]
    return interrupt, failures


def _process_main(setup: Setup, n_trials: int, watched: Connection) -> None:
    """A worker process: its trials, stopped as the module's docstring says; exit status 0, or
    that of the signal that stopped it."""
    signal.signal(SIGINT, signal.SIG_IGN)
    end_with_parent(watched, _stop_self)
    with sigterm_as_interrupt():
        try:
            interrupt = run_trials(load_study(setup), setup, n_trials, signals=(SIGTERM,))
        except KeyboardInterrupt as exc:  # before the first trial
            interrupt = exc
    if interrupt is not None:
        sys.exit(exit_status(interrupt))


def _stop_self() -> None:
    """The parent is gone: stop as on SIGTERM, or at once if that takes too long."""
    os.kill(os.getpid(), SIGTERM)
    time.sleep(STOP_GRACE_S)
    os._exit(1)


def _stop(processes: list[Any]) -> None:
    """SIGTERM to each running worker; wait up to `STOP_GRACE_S` for all (a second Ctrl-C:
    no longer). The caller kills those left."""
    for process in processes:
        if process.is_alive():
            process.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    try:
        for process in processes:
            process.join(max(0.0, deadline - time.monotonic()))
    except KeyboardInterrupt:
        pass


def _fail_abandoned(study: Any, workers: set[str]) -> None:
    """Record as failed the trials that ``workers`` (``host:pid``, all ended) left running."""
    import optuna

    for trial in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,)):
        if trial.user_attrs.get(WORKER_ATTR) in workers:
            study.tell(trial.number, state=optuna.trial.TrialState.FAIL, skip_if_finished=True)


# ------------------------------------------------------------------------------------- Ray tasks


def run_worker(setup: Setup, n_trials: int) -> bool:
    """A Ray task: ``n_trials`` trials of ``setup``'s study; whether none was interrupted."""
    return run_trials(load_study(setup), setup, n_trials, signals=()) is None


def run_ray(study: Any, setup: Setup, parts: list[int], address: str) -> Outcome:
    """Run ``parts[i]`` trials in Ray task i (one CPU each) on the cluster at ``address``; the
    tasks open the study's storage by its URL (a SQLite file by its absolute path)."""
    ray = import_ray(RAY_OPTION)
    started = start_ray(address, RAY_OPTION, log_to_driver=True)
    remote_setup = dataclasses.replace(setup, storage=shared_url(setup.storage) or setup.storage)
    interrupt, failures = None, []
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(run_worker)
        refs = [task.remote(remote_setup, share) for share in parts]
        try:
            for i, ref in enumerate(refs):
                try:
                    ray.get(ref)
                except ray.exceptions.RayError as exc:
                    cause = getattr(exc, "cause", None) or exc  # a task's own error, unwrapped
                    reason = " ".join(str(cause).split())
                    failures.append(f"Ray task {i} failed: {type(cause).__name__}: {reason}")
        except KeyboardInterrupt as exc:
            interrupt = exc
            for ref in refs:
                ray.cancel(ref)  # KeyboardInterrupt in the task: its trial is recorded as failed
            try:
                ray.wait(refs, num_returns=len(refs), timeout=STOP_GRACE_S)
            except KeyboardInterrupt:
                pass
    finally:
        if started:
            ray.shutdown()
    return interrupt, failures
