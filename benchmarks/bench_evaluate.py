"""Time the default leaderboard run, ``python evaluate.py`` (target: under 3 minutes on 2 cores).

    python benchmarks/bench_evaluate.py                  # time `python evaluate.py --out <tmp>`
    taskset -c 0,1 python benchmarks/bench_evaluate.py   # ... pinned to two cores
    python benchmarks/bench_evaluate.py --breakdown 3    # where the time goes, 3 episodes per cell
    python benchmarks/bench_evaluate.py -- --suite quick # options after -- go to evaluate.py

The timed run is the default command with its report written to a temporary directory (so
``reports/default`` is not replaced). After it, the episode wall-clock recorded by the workers
(steps only: reset and the bound are not counted) is summed per agent and per scenario.
``--breakdown N`` instead runs N episodes of every agent x scenario in this process as the
workers do (every agent on the same seeds, each agent's episodes as one batch, so the first
agent's reset records each seed's target side) and splits each episode's time into environment
reset, environment step and the agent's ``predict``.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 180.0


def time_evaluate(extra: list[str]) -> Path:
    """Run evaluate.py in a subprocess; print wall and CPU time and the per-cell sums."""
    out = Path(tempfile.mkdtemp(prefix="bench-evaluate-"))
    command = [sys.executable, "evaluate.py", *extra, "--out", str(out)]
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"$ {' '.join(command)}   ({cpus} usable CPUs)", flush=True)
    start = time.perf_counter()
    subprocess.run(command, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    verdict = "within" if wall <= TARGET_S else "OVER"
    print(f"wall {wall:.1f} s ({verdict} the {TARGET_S:.0f} s target)")
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"load average at the end: {load} (other processes slow the run down)")
    episodes_csv = next(out.glob("*/episodes.csv"))
    _per_cell(episodes_csv)
    return out


def _per_cell(path: Path) -> None:
    rows = list(csv.DictReader(open(path)))
    for key in ("agent", "scenario"):
        groups: dict[str, list[dict[str, str]]] = defaultdict(list)
        for row in rows:
            groups[row[key]].append(row)
        columns = ("episodes", "sum s", "ms/ep", "steps/ep", "ms/step")
        print(f"\n{key:26s} " + " ".join(f"{c:>8s}" for c in columns))
        for name, group in groups.items():
            seconds = sum(float(r["wall_clock_s"]) for r in group)
            steps = sum(int(r["steps"]) for r in group)
            print(
                f"{name:26s} {len(group):8d} {seconds:8.1f} {1e3 * seconds / len(group):8.1f} "
                f"{steps / len(group):9.1f} {1e3 * seconds / steps:8.2f}"
            )
    total = sum(float(r["wall_clock_s"]) for r in rows)
    print(f"\nall episodes: {len(rows)}, {total:.1f} s of episode wall-clock (sum over workers)")
    if rows and "cpu_s" in rows[0]:
        cpu = sum(float(r["cpu_s"]) for r in rows)
        print(
            f"episode CPU time {cpu:.1f} s: on 2 dedicated cores about {cpu / 2:.0f} s of episodes"
        )


class _Timer:
    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    def wrap(self, name: str, func: Any) -> Any:
        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            try:
                return func(*args, **kwargs)
            finally:
                self.seconds[name] += time.perf_counter() - start

        return timed


def breakdown(episodes: int, suite: str) -> None:
    """Split episode time into env reset / env step / predict, per agent and per scenario, as a
    worker plays a chunk: every agent on the same ``episodes`` seeds, one batch per agent
    (`capture_bench.evaluation.running.backends.run_batch`; the first agent's reset records each
    seed's target side, the others replay it)."""
    sys.path.insert(0, str(ROOT))
    from capture_bench.envs.capture_env import CaptureEnv
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.evaluation.running import backends
    from capture_bench.evaluation.running.agents_loading import expand_specs, resolve_agent
    from capture_bench.evaluation.running.suites import ALL, load_suite
    from capture_bench.task.scenarios import list_scenarios, load_scenario

    loaded = load_suite(suite)
    scenarios = list_scenarios() if loaded.scenarios == (ALL,) else list(loaded.scenarios)
    specs = [resolve_agent(s) for s in expand_specs(list(loaded.agents))]
    header = f"{'agent':28s} {'scenario':10s} {'ms/ep':>7s} {'reset':>7s} {'step':>7s}"
    print(header + f" {'predict':>7s} {'steps':>6s}   (ms per episode)")
    totals: dict[str, float] = defaultdict(float)
    originals = {
        (cls, method): getattr(cls, method)
        for cls in (CaptureEnv, CaptureVectorEnv)
        for method in ("reset", "step")
    }
    build = backends.build_agent
    for name in scenarios:
        seeds = load_scenario(name).evaluation_seeds[:episodes]
        for spec in specs:
            timer = _Timer()

            def timed_agent(*args: Any, timer: _Timer = timer) -> Any:
                agent = build(*args)
                agent.predict = timer.wrap("predict", agent.predict)
                return agent

            for (cls, method), func in originals.items():
                setattr(cls, method, timer.wrap(method, func))
            backends.build_agent = timed_agent
            tasks = [backends.EpisodeTask(spec.spec, name, seed) for seed in seeds]
            start = time.perf_counter()
            try:
                records = backends.run_batch(tasks)
            finally:
                for (cls, method), func in originals.items():
                    setattr(cls, method, func)
                backends.build_agent = build
            elapsed = time.perf_counter() - start
            t = {k: 1e3 * v / episodes for k, v in timer.seconds.items()}
            steps = sum(r.steps for r in records)
            print(
                f"{spec.label:28s} {name:10s} {1e3 * elapsed / episodes:7.1f} "
                f"{t.get('reset', 0.0):7.1f} {t.get('step', 0.0):7.1f} "
                f"{t.get('predict', 0.0):7.1f} {steps / episodes:6.1f}"
            )
            for key in ("reset", "step", "predict"):
                totals[key] += t.get(key, 0.0) * episodes
        backends.close_envs()
    grand = sum(totals.values())
    print(
        "\nshare of episode time: "
        + ", ".join(f"{k} {100 * v / grand:.0f}%" for k, v in totals.items())
    )


def main(argv: list[str] | None = None) -> int:
    """Parse the options and run the timing or the breakdown."""
    argv = sys.argv[1:] if argv is None else argv
    extra: list[str] = []
    if "--" in argv:
        cut = argv.index("--")
        argv, extra = argv[:cut], argv[cut + 1 :]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--breakdown",
        type=int,
        metavar="N",
        help="episodes per agent x scenario for the in-process time breakdown",
    )
    parser.add_argument("--suite", default="default", help="suite of the breakdown")
    args = parser.parse_args(argv)
    if args.breakdown:
        breakdown(args.breakdown, args.suite)
    else:
        time_evaluate(extra)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
