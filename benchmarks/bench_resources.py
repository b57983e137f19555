"""Resource hygiene: pybullet clients and memory over many environments and a long evaluation.

Three measurements (Linux: resident set sizes are read from /proc/<pid>/status):

1. ``--envs N`` times ``gymnasium.make("CaptureBench/Paper-v1")``, ``reset(seed=i)``, a few
   random steps, ``close()`` twice. Every pybullet client handed out (``pybullet.connect`` is
   wrapped to record the ids) must be disconnected by ``close()`` itself: checked with
   ``pybullet.isConnected`` while the env object is still alive, so that pybullet's ``__del__``
   cannot hide a ``close()`` that forgets to disconnect. RSS and open file descriptors are sampled
   at 10%, 25%, 50% and 100% of N, with the sizes of the per-process memos that grow by design
   (recorded target sides, at most 16; physical-limit bounds, at most 65,536; cold photogrammetry
   solutions, at most 4,096).
2. The same for ``--vector-envs M`` batched vector envs, ``gymnasium.make_vec(...,
   num_envs=--num-envs)``.
3. An evaluation of ``--episodes E`` episodes through the project's own code path
   (``capture_bench.evaluation.pipeline``: ``plan_evaluation``, then ``run_evaluation`` with its
   report written to a temporary folder). The scenarios publish 100 seeds each, so the scenario is
   ``paper.yaml`` written to that folder with ``seeds.evaluation_count`` raised to E / (number of
   agents) and its name to ``paper_long``, nothing else changed; every agent runs on every seed,
   as in the leaderboard. With ``--workers 1`` every episode runs in this process (serial
   backend: memos and clients are reported too); otherwise on the process backend, as
   ``python evaluate.py`` runs, and each worker's RSS is sampled beside this process's (which
   holds the episode records, ~0.6 kB each, that the report is built from). RSS is sampled every
   ``--sample-every`` episodes; the growth over the first and the last 1,000 episodes is
   reported.

Usage::

    python benchmarks/bench_resources.py          # 1,000 envs, 200 vector envs, 10,000 episodes
    python benchmarks/bench_resources.py --envs 200 --vector-envs 40 --episodes 2000   # shorter
    python benchmarks/bench_resources.py --only evaluation --workers 1   # episodes in-process

Exit status 1 if any pybullet client was left connected.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

# One BLAS thread, as the evaluation's workers run (and as the other benchmarks do).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import gymnasium as gym  # noqa: E402 (after the thread settings)
import numpy as np  # noqa: E402
import yaml  # noqa: E402

import capture_bench  # noqa: E402
from capture_bench.engine.cache import DEFAULT_EPISODE_CACHE  # noqa: E402
from capture_bench.evaluation.pipeline import (  # noqa: E402
    EvaluationConfig,
    plan_evaluation,
    run_evaluation,
    usable_cpus,
)
from capture_bench.interrupts import exit_status, sigterm_as_interrupt  # noqa: E402
from capture_bench.sensing import photogrammetry  # noqa: E402
from capture_bench.sim.world import pybullet  # noqa: E402 (imported quietly there)
from capture_bench.task.scenarios import SCENARIO_DIR  # noqa: E402

ENV_ID = "CaptureBench/Paper-v1"
STEPS = 5  # random steps per environment before close()
AGENTS = "incremental_ik,incremental_ik_uncapped,intercept,dls,oracle"  # all capture in ~2 s


def rss_mb() -> float:
    """Resident set size of this process now, MB (VmRSS of /proc/self/status)."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS line in /proc/self/status")


def open_fds() -> int:
    """File descriptors this process has open now."""
    return len(os.listdir("/proc/self/fd"))


@contextlib.contextmanager
def recorded_connections() -> Iterator[list[int]]:
    """Record the id of every pybullet client connected inside the block (``BulletClient`` calls
    ``pybullet.connect`` through the module, so wrapping it sees every client)."""
    ids: list[int] = []
    connect = pybullet.connect

    def recording_connect(*args: Any, **kwargs: Any) -> int:
        client = connect(*args, **kwargs)
        ids.append(client)
        return client

    pybullet.connect = recording_connect
    try:
        yield ids
    finally:
        pybullet.connect = connect


def memos() -> str:
    """The per-process memos that grow by design, as one line."""
    cold_now, cold_most = photogrammetry.solve_cache_size()
    cache = DEFAULT_EPISODE_CACHE
    recordings, bounds = cache.counts()
    return (
        f"recordings {recordings}/{cache.max_episodes}, bounds {bounds}/{cache.max_limits}, "
        f"cold photogrammetry {cold_now}/{cold_most}"
    )


def checkpoints(count: int) -> list[int]:
    """Where RSS is sampled: 10%, 25%, 50% and 100% of ``count`` (100, 250, 500, 1000 for 1000)."""
    return sorted({max(1, round(count * f)) for f in (0.1, 0.25, 0.5, 1.0)})


def churn(label: str, make: Callable[[], Any], count: int, seed: int = 0) -> dict[str, Any]:
    """Make, reset, step and close ``count`` environments; check clients, sample RSS.

    Returns:
        ``{"rss": {envs: MB}, "clients": ids handed out, "left": ids still connected after their
        env's close() or at the end}``.
    """
    rng = np.random.default_rng(seed)
    samples: dict[int, float] = {}
    left: list[int] = []
    wanted = set(checkpoints(count))
    print(f"\n{label}: {count} x make, reset, {STEPS} steps, close() twice", flush=True)
    print(f"{'envs':>6s} {'RSS MB':>8s} {'fds':>4s} {'s':>6s}   memos", flush=True)
    start = time.perf_counter()
    with recorded_connections() as clients:
        for i in range(1, count + 1):
            opened = len(clients)
            env = make()
            env.reset(seed=i)
            for _ in range(STEPS):
                action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
                env.step(action)
            env.close()
            env.close()  # safe twice
            # the env is still referenced here: a client is closed by close(), not by __del__
            left += [c for c in clients[opened:] if pybullet.isConnected(physicsClientId=c)]
            del env
            if i in wanted:
                samples[i] = rss_mb()
                seconds = time.perf_counter() - start
                line = f"{i:6d} {samples[i]:8.1f} {open_fds():4d} {seconds:6.1f}   {memos()}"
                print(line, flush=True)
    still = sorted({c for c in clients if pybullet.isConnected(physicsClientId=c)})
    print(
        f"pybullet clients: {len(clients)} connected, {len(left)} left connected by close(), "
        f"{len(still)} connected now ({len(set(clients))} distinct ids, pybullet reuses them)"
    )
    first, last = min(samples), max(samples)
    if last > first:
        per_100 = 100 * (samples[last] - samples[first]) / (last - first)
        print(f"RSS growth from {first} to {last} envs: {per_100:+.2f} MB per 100 envs")
    return {"rss": samples, "clients": clients, "left": left + still}


def long_scenario(directory: Path, seeds: int) -> Path:
    """``paper.yaml`` with ``seeds`` published evaluation seeds, written to ``directory``."""
    data = yaml.safe_load((SCENARIO_DIR / "paper.yaml").read_text())
    data["name"] = "paper_long"
    data["seeds"]["evaluation_count"] = seeds
    path = directory / "paper_long.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def records_mb(records: list[Any]) -> float:
    """Memory held by the episode records (each distinct object counted once), MB."""
    seen: set[int] = set()
    total = 0
    for record in records:
        for obj in (record, record.__dict__, *record.__dict__.values()):
            if id(obj) not in seen:
                seen.add(id(obj))
                total += sys.getsizeof(obj)
    return total / 2**20


def _parents() -> dict[int, int]:
    """Parent pid of every process now, from /proc/<pid>/stat."""
    parents = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:  # gone since listdir
                continue
            parents[int(entry)] = int(stat.rsplit(")", 1)[1].split()[1])
    return parents


def worker_pids() -> list[int]:
    """The evaluation's worker processes: this process's deepest descendants (the workers fork
    from the forkserver, a child of this process beside multiprocessing's resource tracker)."""
    parents = _parents()
    level, deepest = [os.getpid()], []
    while level:
        deepest = level
        level = [pid for pid, parent in parents.items() if parent in level]
    return sorted(deepest) if deepest != [os.getpid()] else []


def rss_of(pid: int) -> float | None:
    """Resident set size of process ``pid``, MB (None if it has gone)."""
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def evaluation(
    episodes: int, agents: list[str], workers: int, sample_every: int, curve: bool = False
) -> dict[str, Any]:
    """Run the evaluation pipeline on ``episodes`` episodes, sampling RSS as it goes: of this
    process, and with ``workers`` > 1 of each worker process (where the episodes then run)."""
    seeds = math.ceil(episodes / len(agents))
    with tempfile.TemporaryDirectory(prefix="bench-resources-") as work:
        return _evaluation(Path(work), seeds, agents, workers, sample_every, curve)


def _evaluation(
    work: Path, seeds: int, agents: list[str], workers: int, sample_every: int, curve: bool
) -> dict[str, Any]:
    """`evaluation` with its scenario and report in ``work``."""
    total = seeds * len(agents)
    backend = "serial" if workers == 1 else "process"
    config = EvaluationConfig(
        agents=agents,
        scenarios=[str(long_scenario(work, seeds))],
        episodes=seeds,
        backend=backend,
        workers=workers,
        out=work / "reports",
    )
    plan = plan_evaluation(config)
    where = f"process backend, {workers} workers"
    if workers == 1:
        where = "serial backend: every episode in this process"
    print(
        f"\nevaluation: {total} episodes = {len(agents)} agents x {seeds} seeds of paper "
        f"({where}; the report to a temporary folder)",
        flush=True,
    )
    names: dict[int, str] = {}  # worker pid -> its column
    samples: dict[int, dict[str, float]] = {0: {"main": rss_mb()}}
    done = 0
    start = time.perf_counter()

    def sample() -> None:
        row = {"main": rss_mb()}
        for pid in worker_pids() if workers > 1 else []:
            mb = rss_of(pid)
            if mb is not None:
                row[names.setdefault(pid, f"worker {len(names) + 1}")] = mb
        samples[done] = row
        if len(samples) == 2:
            columns = " ".join(f"{label + ' MB':>11s}" for label in row)
            print(f"{'episodes':>8s} {columns} {'fds':>4s} {'s':>6s}", flush=True)
        if curve or done % (10 * sample_every) < sample_every or done == total:
            values = " ".join(f"{mb:11.1f}" for mb in row.values())
            memo = f"   {memos()}" if workers == 1 else ""
            seconds = time.perf_counter() - start
            print(f"{done:8d} {values} {open_fds():4d} {seconds:6.1f}{memo}", flush=True)

    def progress(count: int) -> None:
        nonlocal done
        before, done = done, done + count
        if done // sample_every > before // sample_every or done == total:
            sample()

    with recorded_connections() as clients:
        data, _ = run_evaluation(plan, config, "bench_resources", progress)
    after = rss_mb()
    still = sorted({c for c in clients if pybullet.isConnected(physicsClientId=c)})
    captured = sum(r.captured for r in data.records)
    held = records_mb(data.records)
    print(
        f"captured {captured} of {len(data.records)}; this process after writing the report: "
        f"{after:.1f} MB; the {len(data.records)} episode records it holds: {held:.1f} MB"
    )
    if workers == 1:
        print(f"pybullet clients: {len(clients)} connected, {len(still)} connected now")
    window = min(1000, total // 2)
    for label in samples[total]:
        rss = {n: row[label] for n, row in samples.items() if label in row}
        h = min(n for n in rss if n > 0)  # imports, the env and the first recordings done
        first = max(n for n in rss if n <= max(window, h))
        last = min(n for n in rss if n >= total - window)
        print(
            f"{label}: {rss[h]:.1f} MB at episode {h}, {rss[total]:.1f} MB at {total}; growth "
            f"over episodes {h}-{first}: {rss[first] - rss[h]:+.1f} MB, over {last}-{total}: "
            f"{rss[total] - rss[last]:+.1f} MB"
        )
    return {"rss": samples, "left": still}


def main(argv: list[str] | None = None) -> int:
    """Parse the options and run the measurements; exit status 1 if a client was left open."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", type=int, default=1000, help="single envs made and closed")
    parser.add_argument("--vector-envs", type=int, default=200, help="vector envs made and closed")
    parser.add_argument("--num-envs", type=int, default=8, help="sub-envs of each vector env")
    parser.add_argument("--episodes", type=int, default=10_000, help="episodes of the evaluation")
    parser.add_argument(
        "--agents", default=AGENTS, help=f"comma-separated agents of the evaluation ({AGENTS})"
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=usable_cpus(),
        help="evaluation workers (default: every usable CPU); 1: the serial backend, in process",
    )
    parser.add_argument(
        "--sample-every", type=int, default=100, help="episodes between RSS samples"
    )
    parser.add_argument(
        "--curve", action="store_true", help="print every RSS sample (default: every tenth)"
    )
    parser.add_argument(
        "--only", choices=("envs", "vector", "evaluation"), help="run one measurement only"
    )
    args = parser.parse_args(argv)
    print(f"capture-bench {capture_bench.__version__}: resource hygiene, RSS {rss_mb():.1f} MB")
    try:
        with sigterm_as_interrupt():  # the evaluation's workers are then ended, not orphaned
            left = measure(args)
    except KeyboardInterrupt as interrupt:
        print("interrupted")
        return exit_status(interrupt)
    if left:
        print(f"LEAK: pybullet clients left connected: {sorted(set(left))}")
        return 1
    return 0


def measure(args: argparse.Namespace) -> list[int]:
    """Run the measurements the options ask for; the pybullet clients left connected."""
    left: list[int] = []
    if args.envs and args.only in (None, "envs"):
        left += churn("single env", lambda: gym.make(ENV_ID), args.envs)["left"]
    if args.vector_envs and args.only in (None, "vector"):
        make = lambda: gym.make_vec(ENV_ID, num_envs=args.num_envs)  # noqa: E731
        label = f"vector env of {args.num_envs}"
        left += churn(label, make, args.vector_envs)["left"]
    if args.episodes and args.only in (None, "evaluation"):
        agents = args.agents.split(",")
        result = evaluation(args.episodes, agents, args.workers, args.sample_every, args.curve)
        left += result["left"]
    return left


if __name__ == "__main__":
    raise SystemExit(main())
