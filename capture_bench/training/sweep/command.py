"""Training sweeps on Ray: ``python -m capture_bench sweep``.

Trains every combination of ``--algos``, ``--scenarios`` and ``--seeds``, each run one Ray task
(`capture_bench.training.sweep.task.train_run`, asking Ray for ``--cpus-per-run`` CPUs and
``--gpus-per-run`` GPUs) on a new local Ray instance (on the loopback; no other cluster is
joined) or on the running cluster ``--ray-address`` names (`capture_bench.ray_cluster`
starts or joins it and ships this checkout to the nodes). Each run is what
``train.py`` writes, at ``<runs>/<scenario>-<arm>-<seed>`` (the naming of ``curves --train``:
`capture_bench.training.common.run_plan`). The task trains in a temporary directory of its node and
sends the directory back as a tar archive; this process unpacks it beside its place under
``--runs`` and renames it in (``config.json``'s ``run_dir`` set to that place), so the nodes
share no filesystem and no run directory is ever half-written.

A sweep resumes where it stopped: a run holding ``metadata.json`` is finished and kept; one with a
checkpoint is sent to its node and resumed from its newest checkpoint (train.py ``--resume``, to
its own total); any other is trained from the start. Ctrl-C (or SIGTERM) cancels the runs: each
running one saves a checkpoint (train.py's own interrupt) and comes back, resumable, and the
command exits 130 (143); a second Ctrl-C stops waiting for them. A run that fails is reported
with its error line and the others go on; the summary (``<runs>/sweep.json``: each run's outcome,
the Ray node it ran on, its error and the end of its output) is written at the end, and the exit
status is 1 if any run failed.

Every option is checked before Ray starts, and a mistake is one line on stderr, exit status 2,
with nothing written: the algorithms, scenarios and seeds (training seeds of every scenario:
``0-9`` or ``0 1 2``), ``--runs`` (writable; a folder there with a run's name must be a run), and
each new run's options resolved as train.py resolves them (its ``prepare``, in a temporary
folder). The cluster must then answer (in seconds; one that does not is one line, exit status
2) and have a node with the CPUs and GPUs a run asks for.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

from capture_bench import ray_cluster
from capture_bench.argparsing import OneLineParser
from capture_bench.files import atomic_write, check_writable
from capture_bench.interrupts import exit_status, signals_ignored
from capture_bench.paths import CHECKOUT_DIR
from capture_bench.task.scenarios import ConfigError, list_scenarios, load_scenario
from capture_bench.training.common import run_plan
from capture_bench.training.common.run_plan import is_finished, resumable_step, run_path, train_argv
from capture_bench.training.config.hyperparameters import ALGORITHMS
from capture_bench.training.seeds import check_training_seed
from capture_bench.training.sweep.driver import Run
from capture_bench.training.sweep.task import RunSpec, pack

PROG = "python -m capture_bench sweep"
NAME = "sweep"  # in error lines: "sweep: error: ..."
#: The summary of the last sweep, under ``--runs``.
SUMMARY_FILE = "sweep.json"
#: Not shipped to the nodes beside `capture_bench.ray_cluster.RAY_EXCLUDES`: training
#: reads no shipped model.
EXCLUDES = ["/models"]


def parse_seeds(words: list[str]) -> list[int]:
    """Seeds from ``0 1 2`` and ``0-9`` forms (commas too), in order, each once.

    Raises:
        ConfigError: a word that is neither a whole number nor a range FIRST-LAST with
            FIRST <= LAST.
    """
    seeds: list[int] = []
    for word in words:
        for part in word.split(","):
            match = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
            if match is None:
                raise ConfigError(
                    f"--seeds {word}: expected whole numbers (0 1 2) or ranges FIRST-LAST (0-9)"
                )
            first = int(match[1])
            last = first if match[2] is None else int(match[2])
            if last < first:
                raise ConfigError(
                    f"--seeds {part.strip()}: the range ends before it starts; write FIRST-LAST "
                    f"with FIRST <= LAST ({last}-{first})"
                )
            seeds.extend(range(first, last + 1))
    return list(dict.fromkeys(seeds))


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=PROG,
        description="Train every combination of algorithms, scenarios and training seeds, each "
        "run a Ray task, on this machine or a Ray cluster; resumable (finished runs are kept, "
        "interrupted ones resume from their checkpoint).",
        epilog="examples:\n"
        f"  {PROG} --algos ppo sac --scenarios paper grasp --seeds 0-9\n"
        f"  {PROG} --algos ppo --scenarios paper --seeds 0 1 2 --ray-address 10.0.0.1:6379\n"
        f"  {PROG} --algos ppo --scenarios paper --seeds 0-4 --set n_envs=16 "
        "--total-timesteps 500000",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--algos",
        nargs="+",
        required=True,
        choices=ALGORITHMS,
        metavar="ALGO",
        help=f"algorithms ({', '.join(ALGORITHMS)})",
    )
    parser.add_argument(
        "--scenarios", nargs="+", required=True, metavar="SCENARIO", help="scenario names"
    )
    parser.add_argument(
        "--seeds",
        nargs="+",
        required=True,
        metavar="SEEDS",
        help="training seeds, as train.py's --seed: 0 1 2, or a range 0-9",
    )
    parser.add_argument(
        "--pixels",
        action="store_true",
        help="also train each algorithm on the camera's pixels, as <algo>-pixels runs "
        "(configs/pixels/<algo>.yaml: ppo has one)",
    )
    parser.add_argument(
        "--runs", default="runs/sweep", help="where the runs land (default: runs/sweep)"
    )
    parser.add_argument(
        "--set",
        action="append",
        dest="overrides",
        metavar="KEY=VALUE",
        help="a hyper-parameter for every new run, as train.py's --set; repeat for more",
    )
    parser.add_argument(
        "--config", help="hyper-parameter YAML for every new run, as train.py's --config"
    )
    parser.add_argument(
        "--total-timesteps", type=int, help="environment steps of every new run, in total"
    )
    parser.add_argument(
        "--device",
        choices=("auto", "cpu", "cuda"),
        help="torch device of every run (default: cuda with --gpus-per-run, else cpu)",
    )
    parser.add_argument(
        "--ray-address",
        help="a running cluster's address (HOST:PORT, as `ray start --head` prints; auto: the "
        "one `ray start` started on this machine; ray://HOST:PORT); default: a new Ray instance "
        "on this machine, on the loopback",
    )
    parser.add_argument(
        "--cpus-per-run", type=float, default=1.0, help="CPUs Ray reserves per run (default 1)"
    )
    parser.add_argument(
        "--gpus-per-run",
        type=float,
        default=0.0,
        help="GPUs Ray reserves per run (default 0; 0.5 lets two runs share one)",
    )
    return parser


def check_train_options(
    arms: list[str], scenarios: list[str], seed: int, options: list[str]
) -> list[str]:
    """Resolve every arm x scenario's new-run options as train.py does (its ``prepare``, in a
    temporary folder); return the notes it printed, each once.

    Raises:
        ConfigError: the options do not make a valid train.py run; the message names the arm and
            the scenario.
    """
    from capture_bench.training.common.checkpoint import CheckpointError
    from capture_bench.training.common.run import prepare
    from capture_bench.training.config.options import parse_args

    notes: list[str] = []
    with tempfile.TemporaryDirectory(prefix="capture-bench-sweep-check-") as tmp:
        for scenario in scenarios:
            for arm in arms:
                run_dir = Path(tmp) / f"{scenario}-{arm}"
                argv = train_argv(run_dir, scenario, arm, seed, False, [*options, "--device=cpu"])
                printed = io.StringIO()
                try:
                    with contextlib.redirect_stdout(printed):
                        prepare(*parse_args(argv))
                except (ConfigError, CheckpointError, OSError) as exc:
                    raise ConfigError(f"{arm} on {scenario}: {exc}") from None
                notes += [n for n in printed.getvalue().splitlines() if n and n not in notes]
    return notes


def plan(runs: Path, scenarios: list[str], arms: list[str], seeds: list[int]) -> list[Run]:
    """Every run of the sweep, each marked ``kept`` (finished) or with the step it resumes from.

    Raises:
        ConfigError: a folder with a run's name that is not a run of train.py.
    """
    planned = []
    for scenario in scenarios:
        for arm in arms:
            for seed in seeds:
                run_dir = run_path(runs, scenario, arm, seed)
                run = Run(run_dir.name, scenario, arm, seed)
                if run_dir.exists() and not (
                    run_dir.is_dir()
                    and ((run_dir / "config.json").is_file() or not any(run_dir.iterdir()))
                ):
                    raise ConfigError(
                        f"{run_dir}: not a run of train.py (no config.json), and the sweep would "
                        "replace it; move it away or choose another --runs"
                    )
                if is_finished(run_dir):
                    run.outcome = "kept"
                else:
                    run.resumed_from = resumable_step(run_dir)
                planned.append(run)
    return planned


@dataclass
class Sweep:
    """A sweep's checked options and its runs.

    Attributes:
        runs: where the runs land (``--runs``).
        planned: every run, in order (scenario, arm, seed).
        options: train.py options of every new run (``--set``, ``--total-timesteps``).
        config: ``(path as given, bytes)`` of ``--config``, or None.
        device: train.py's ``--device`` of every run.
        cpus, gpus: what Ray reserves per run.
        address: ``--ray-address``, or None.
        command: the command line, for the summary.
    """

    runs: Path
    planned: list[Run]
    options: list[str]
    config: tuple[str, bytes] | None
    device: str
    cpus: float
    gpus: float
    address: str | None
    command: str

    def spec(self, run: Run) -> RunSpec:
        """What the node needs to train ``run`` (its directory, packed, to resume one)."""
        directory = run_path(self.runs, run.scenario, run.arm, run.seed)
        partial = pack(directory) if run.resumed_from is not None else None
        return RunSpec(
            run.name, run.scenario, run.arm, run.seed, tuple(self.options), self.device,
            self.config, partial,
        )  # fmt: skip


def _read_config(path: str | None, pixels: bool) -> tuple[str, bytes] | None:
    if path is None:
        return None
    if pixels:
        raise ConfigError(
            "--config with --pixels: the pixel runs read configs/pixels/<algo>.yaml; give one "
            "or the other"
        )
    try:
        return path, Path(path).read_bytes()
    except OSError as exc:
        raise ConfigError(f"--config {path}: cannot be read ({exc.strerror or exc})") from None


def resolve(argv: list[str]) -> tuple[Sweep, list[str]]:
    """The sweep ``argv`` asks for, every option checked, and train.py's notes on its new runs.

    Raises:
        ConfigError: what is wrong, in one message.
        SystemExit: argparse's (--help, or a malformed option, already printed).
    """
    args = build_parser().parse_args(argv)
    seeds = parse_seeds(args.seeds)
    valid = list_scenarios()
    for name in args.scenarios:
        if name not in valid:
            raise ConfigError(f"--scenarios {name}: no such scenario; valid: {', '.join(valid)}")
    scenarios = list(dict.fromkeys(args.scenarios))
    for name in scenarios:
        for seed in seeds:
            check_training_seed(seed, load_scenario(name))
    if not (args.cpus_per_run > 0 and args.gpus_per_run >= 0):
        raise ConfigError(
            f"--cpus-per-run {args.cpus_per_run:g} --gpus-per-run {args.gpus_per_run:g}: "
            "expected CPUs above 0 and GPUs at least 0"
        )
    device = args.device or ("cuda" if args.gpus_per_run else "cpu")
    if device == "cuda" and not args.gpus_per_run:
        raise ConfigError(
            "--device cuda: Ray gives a run a GPU only where it asks for one; add "
            "--gpus-per-run 1 (or a share, 0.5)"
        )
    arms = run_plan.arms(args.algos, args.pixels)
    config = _read_config(args.config, args.pixels)
    options = [f"--set={item}" for item in args.overrides or []]
    if args.total_timesteps is not None:
        options += ["--total-timesteps", str(args.total_timesteps)]
    runs = Path(args.runs)
    check_writable(runs, "--runs")
    planned = plan(runs, scenarios, arms, seeds)
    fresh = [r for r in planned if r.outcome != "kept" and r.resumed_from is None]
    notes = check_train_options(
        list(dict.fromkeys(r.arm for r in fresh)),
        list(dict.fromkeys(r.scenario for r in fresh)),
        seeds[0],
        options + (["--config", args.config] if args.config else []),
    )
    command = " ".join([PROG, *argv])
    sweep = Sweep(
        runs, planned, options, config, device, args.cpus_per_run, args.gpus_per_run,
        args.ray_address, command,
    )  # fmt: skip
    return sweep, notes


def _excludes(runs: Path) -> list[str]:
    """`EXCLUDES`, and ``--runs`` where it lies inside the checkout shipped to the nodes."""
    try:
        inside = runs.resolve().relative_to(CHECKOUT_DIR)
    except ValueError:
        return list(EXCLUDES)
    return [*EXCLUDES, "/" + inside.as_posix()] if inside.parts else list(EXCLUDES)


def run_sweep(sweep: Sweep) -> int:
    """Train the sweep's unfinished runs on Ray, write the summary; the exit status.

    Raises:
        ConfigError: the cluster does not answer, or has no node as large as a run asks.
    """
    todo = [r for r in sweep.planned if r.outcome != "kept"]
    resuming = sum(r.resumed_from is not None for r in todo)
    plan_line = (
        f"sweep: {len(sweep.planned)} runs ({len(sweep.planned) - len(todo)} finished and kept, "
        f"{resuming} to resume, {len(todo) - resuming} new) -> {sweep.runs}"
    )
    if not todo:
        print(plan_line)
        return finish(sweep, {}, None)
    from capture_bench.training.sweep import driver as sweep_ray

    started = ray_cluster.start_ray(sweep.address, "the sweep", excludes=_excludes(sweep.runs))
    try:
        sweep_ray.check_resources(sweep.cpus, sweep.gpus)
        print(plan_line, flush=True)
        interrupt = sweep_ray.execute(todo, sweep.runs, sweep.spec, sweep.cpus, sweep.gpus)
    except BaseException:
        if started:
            _shutdown()
        raise
    with signals_ignored():  # ending: a second Ctrl-C must not leave Ray or the summary half done
        nodes = sweep_ray.nodes()
        if started:
            _shutdown()
        return finish(sweep, nodes, interrupt)


def _shutdown() -> None:
    import ray

    ray.shutdown()


def finish(sweep: Sweep, nodes: dict[str, dict], interrupt: KeyboardInterrupt | None) -> int:
    """Write the summary (``<runs>/sweep.json``: the command, the nodes that ran something,
    every run's outcome) and say what became of the runs; the exit status."""
    used = {r.node_id for r in sweep.planned}
    summary = {
        "command": sweep.command,
        "ray_address": sweep.address,
        "nodes": {node: about for node, about in nodes.items() if node in used},
        "runs": [asdict(r) for r in sweep.planned],
    }
    sweep.runs.mkdir(parents=True, exist_ok=True)
    atomic_write(sweep.runs / SUMMARY_FILE, json.dumps(summary, indent=2).encode())
    outcomes = [r.outcome for r in sweep.planned]
    counts = ", ".join(f"{outcomes.count(o)} {o}" for o in dict.fromkeys(outcomes))
    print(f"sweep: {counts}; summary: {sweep.runs / SUMMARY_FILE}")
    for run in sweep.planned:
        if run.outcome == "failed":
            print(f"{NAME}: {run.name} failed: {run.error}", file=sys.stderr)
    if interrupt is not None:
        return exit_status(interrupt)
    return 1 if "failed" in outcomes else 0


def main(argv: list[str] | None = None) -> int:
    """``python -m capture_bench sweep``; the exit status: 0, 1 if a run failed, 2 for bad input
    (one line on stderr, nothing written), 130 or 143 when interrupted."""
    args = sys.argv[1:] if argv is None else list(argv)
    try:
        sweep, notes = resolve(args)
        for note in notes:
            print(note)
        return run_sweep(sweep)
    except ConfigError as exc:
        print(f"{NAME}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # argparse: --help (0) or a bad option (2, already printed)
        return int(exc.code or 0)
    except KeyboardInterrupt as exc:  # before the runs were sent: nothing to save
        print("\ninterrupted before any run started; nothing written", file=sys.stderr)
        return exit_status(exc)


if __name__ == "__main__":
    raise SystemExit(main())
