"""The driver's side of a sweep on Ray: the runs sent as tasks, their results installed under
``--runs`` as they come back, the cancellation on Ctrl-C, and what the summary says of the
nodes (`capture_bench.training.sweep.command` is the command)."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from capture_bench.files import atomic_write
from capture_bench.interrupts import interrupts_deferred, sigterm_as_interrupt
from capture_bench.task.scenarios import ConfigError
from capture_bench.training.common.run_plan import resumable_step
from capture_bench.training.sweep.task import RunResult, RunSpec, train_run, unpack

#: Prefix of the folders a run is unpacked into, under ``--runs``, before it is renamed in.
STAGING_PREFIX = ".sweep-"
#: train.py's exit status after Ctrl-C / SIGTERM (a cancelled task's).
INTERRUPTED = (130, 143)


@dataclass
class Run:
    """One run of the sweep and what became of it.

    Attributes:
        name: ``<scenario>-<arm>-<seed>``, its directory under ``--runs``.
        scenario, arm, seed: what it trains.
        resumed_from: the step of the checkpoint it resumes from, or None for a new run.
        outcome: ``kept`` (finished before), ``trained``, ``resumed``, ``failed``,
            ``interrupted`` (cancelled while training; its checkpoint came back), ``not
            started``.
        node_id, node_ip: the Ray node it ran on.
        error: one line saying why it failed or stopped, or None.
        output: the end of a failed or interrupted run's output.
    """

    name: str
    scenario: str
    arm: str
    seed: int
    resumed_from: int | None = None
    outcome: str = "not started"
    node_id: str = ""
    node_ip: str = ""
    error: str | None = None
    output: str = ""

    def line(self) -> str:
        """One line on what became of the run."""
        where = f" on node {self.node_id[:12]} ({self.node_ip})" if self.node_id else ""
        if self.outcome == "resumed":
            return f"{self.name}: resumed from step {self.resumed_from} and finished{where}"
        if self.outcome in ("failed", "interrupted"):
            return f"{self.name}: {self.outcome.upper()}{where}: {self.error}"
        return f"{self.name}: {self.outcome}{where}"


def _alive_nodes() -> list[dict[str, float]]:
    import ray

    return [n["Resources"] for n in ray.nodes() if n.get("Alive")]


def capacity(cpus: float, gpus: float) -> int:
    """How many runs of ``cpus`` CPUs and ``gpus`` GPUs the cluster's nodes hold at once."""
    total = 0
    for node in _alive_nodes():
        fits = node.get("CPU", 0) // cpus
        if gpus:
            fits = min(fits, node.get("GPU", 0) // gpus)
        total += int(fits)
    return total


def check_resources(cpus: float, gpus: float) -> None:
    """Raise [`ConfigError`][capture_bench.ConfigError] unless a node of the cluster has ``cpus``
    CPUs and ``gpus``
    GPUs (Ray would wait for one forever)."""
    if capacity(cpus, gpus):
        return
    nodes = _alive_nodes()
    sizes = ", ".join(sorted({f"{n.get('CPU', 0):g} CPU / {n.get('GPU', 0):g} GPU" for n in nodes}))
    fix = " (--gpus-per-run 0 trains on CPUs)" if gpus else ""
    raise ConfigError(
        f"--cpus-per-run {cpus:g} --gpus-per-run {gpus:g}: no node of the Ray cluster has that "
        f"much (its nodes: {sizes or 'none'}){fix}"
    )


def install(result: RunResult, runs: Path) -> bool:
    """Put a run's directory from its archive at ``runs/<name>``, whole: unpacked beside it, then
    renamed in (replacing what was there), its ``config.json``'s ``run_dir`` set to that place. A
    failed or interrupted run's directory is installed only where it holds a checkpoint to resume
    from. Returns whether it was installed."""
    if result.archive is None:
        return False
    runs.mkdir(parents=True, exist_ok=True)
    staging = runs / f"{STAGING_PREFIX}{result.name}-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    unpack(result.archive, staging)
    if result.status != 0 and resumable_step(staging) is None:
        shutil.rmtree(staging)
        return False
    target = runs / result.name
    saved = staging / "config.json"
    if saved.is_file():  # it trained in a node's temporary folder
        data = json.loads(saved.read_text())
        data["config"]["run_dir"] = str(target)
        atomic_write(saved, json.dumps(data, indent=2).encode())
    old = runs / f"{STAGING_PREFIX}old-{result.name}-{os.getpid()}"
    if target.exists():
        target.rename(old)
    staging.rename(target)
    shutil.rmtree(old, ignore_errors=True)
    return True


def record(run: Run, result: RunResult, runs: Path) -> None:
    """Install the run's directory and note its outcome, node and error."""
    installed = install(result, runs)
    run.node_id, run.node_ip = result.node_id, result.node_ip
    if result.status == 0:
        run.outcome = "resumed" if run.resumed_from is not None else "trained"
    elif result.status in INTERRUPTED and installed:
        run.outcome, run.output = "interrupted", result.output
        step = resumable_step(runs / result.name)
        run.error = f"interrupted; checkpoint at step {step}: run the sweep again to resume it"
    else:
        run.outcome = "interrupted" if result.status in INTERRUPTED else "failed"
        run.error, run.output = result.error, result.output


def execute(
    todo: list[Run],
    runs: Path,
    spec: Callable[[Run], RunSpec],
    cpus: float,
    gpus: float,
) -> KeyboardInterrupt | None:
    """Run ``todo`` on Ray (initialised here), each with ``cpus`` CPUs and ``gpus`` GPUs,
    installing each run and noting its outcome as it ends; the interrupt (Ctrl-C or SIGTERM)
    that stopped the sweep, or None.

    Runs are sent in order, at most twice as many at a time as the cluster holds at once, so this
    process keeps only their archives (a resumed run's directory goes with it) in memory. On an
    interrupt nothing more is sent and every run sent is cancelled: one not started never
    starts, one training gets KeyboardInterrupt, saves a checkpoint and comes back; this waits
    for them (a second interrupt stops waiting)."""
    import ray

    remote = ray.remote(num_cpus=cpus, num_gpus=gpus, max_retries=0)(train_run)
    queue = list(todo)
    limit = 2 * max(capacity(cpus, gpus), 1)
    refs: dict[Any, Run] = {}
    pending: list[Any] = []

    def collect(done: list[Any]) -> None:
        for ref in done:
            run = refs.pop(ref)
            try:
                result = ray.get(ref)
                with interrupts_deferred():  # a run directory is never left half-renamed
                    record(run, result, runs)
            except ray.exceptions.TaskCancelledError:
                continue  # cancelled before it started: "not started"
            except ray.exceptions.RayError as exc:  # its worker or its node died, ...
                lines = [s.strip() for s in str(exc).splitlines() if s.strip()]
                run.outcome = "failed"
                run.error = f"{type(exc).__name__}: {lines[-1] if lines else exc}"
            print(run.line(), flush=True)

    def wait_all() -> None:
        nonlocal pending
        while queue or pending:
            while queue and len(pending) < limit:
                run = queue.pop(0)
                ref = remote.remote(spec(run))
                refs[ref] = run
                pending.append(ref)
            done, pending = ray.wait(pending, num_returns=1, timeout=1.0)
            collect(done)

    with sigterm_as_interrupt():
        try:
            wait_all()
        except KeyboardInterrupt as exc:
            queue.clear()  # never sent: "not started"
            print(
                f"\ninterrupted: cancelling {len(pending)} runs; those training save a "
                "checkpoint and come back (Ctrl-C again stops waiting)",
                file=sys.stderr,
                flush=True,
            )
            for ref in pending:
                ray.cancel(ref)
            with contextlib.suppress(KeyboardInterrupt):
                wait_all()
            return exc
    return None


def nodes() -> dict[str, dict[str, Any]]:
    """The cluster's nodes: ``{node ID: {"ip", "head"}}`` (the head holds Ray's
    ``node:__internal_head__`` resource)."""
    import ray

    return {
        n["NodeID"]: {
            "ip": n.get("NodeManagerAddress", ""),
            "head": "node:__internal_head__" in n.get("Resources", {}),
        }
        for n in ray.nodes()
    }
