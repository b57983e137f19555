"""``python -m capture_bench``: the package's commands.

``python -m capture_bench evaluate ...``, ``python -m capture_bench train ...`` and
``python -m capture_bench tune ...`` run the same ``main`` as ``python evaluate.py`` /
``python train.py`` / ``python tune.py`` and the console scripts ``capture-bench-evaluate`` /
``capture-bench-train`` / ``capture-bench-tune``, with the same options.

``python -m capture_bench curves ...``: learning curves from several training seeds
(`capture_bench.training.curves.command`).

``python -m capture_bench zoo-hyperparams``: the RL Zoo's hyper-parameter files
(``configs/zoo/<algo>.yml``) made from ``configs/algos/`` (`capture_bench.training.zoo.command`).

``python -m capture_bench sweep ...``: train every combination of algorithms, scenarios and
training seeds, each run a Ray task, on this machine or a Ray cluster
(`capture_bench.training.sweep.command`).

``python -m capture_bench dataset ...``: record agents' episodes on a scenario's training or
validation seeds as a Minari dataset (`capture_bench.datasets.command`; needs the datasets extra).

``python -m capture_bench list``: what is installed, and what is broken, in one screen. It prints
the valid scenarios (name, registered gymnasium ID, evaluation and training seed ranges), the
invalid scenario files with their error (file, key, what is valid), the suites and the algorithm
configs (each with its error if it does not load). Nothing here raises on a bad file: listing is
how a user finds the bad file.
"""

from __future__ import annotations

import argparse
import functools
import sys
from collections.abc import Callable
from typing import Any

from capture_bench.argparsing import OneLineParser
from capture_bench.interrupts import exit_status, sigterm_as_interrupt

PROG = "python -m capture_bench"
DELEGATED = {
    "evaluate": "evaluate agents on a suite and write the leaderboard report",
    "train": "train a Stable-Baselines3 policy on a scenario",
    "tune": "tune an algorithm's hyper-parameters with Optuna (needs the tune extra)",
    "curves": "learning curves of several algorithms and training seeds against incremental_ik",
    "zoo-hyperparams": "write the RL Zoo's hyper-parameter files (configs/zoo/) from our configs",
    "sweep": "train every combination of algorithms, scenarios and seeds as Ray tasks (needs the "
    "ray extra)",
    "dataset": "record agents' episodes as a Minari dataset for imitation and offline RL (needs "
    "the datasets extra)",
}


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=PROG,
        hint=" (see --help)",
        description="capture-bench: evaluate agents, train and tune policies, list what is "
        "installed.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, what in DELEGATED.items():
        where = f"the options of {name}.py: " if name in ("evaluate", "train", "tune") else ""
        commands.add_parser(name, help=f"{what} ({where}{PROG} {name} --help)")
    commands.add_parser(
        "list",
        help="list the valid scenarios (name, env ID, seed ranges), invalid scenario files with "
        "their error, the suites and the algorithm configs",
        description="List the valid scenarios (name, env ID, seed ranges), invalid scenario "
        "files with their error, the suites and the algorithm configs.",
    )
    return parser


def _seeds(start: int, count: int) -> str:
    return f"{start}-{start + count - 1} ({count})"


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _try(load: Callable[[], Any]) -> tuple[Any, str | None]:
    """``(load(), None)``, or ``(None, the error's message)`` for a bad-input error."""
    from capture_bench.evaluation.errors import EvaluationError
    from capture_bench.task.scenarios import ConfigError

    try:
        return load(), None
    except (ConfigError, EvaluationError) as exc:
        return None, _one_line(str(exc))


def list_everything() -> list[str]:
    """The lines ``python -m capture_bench list`` prints."""
    from capture_bench.evaluation.running.suites import SUITES_DIR, list_suites, load_suite
    from capture_bench.task.scenarios import (
        SCENARIO_DIR,
        invalid_scenarios,
        list_scenarios,
        load_scenario,
    )
    from capture_bench.training.config.hyperparameters import (
        ALGO_DIR,
        ALGORITHMS,
        load_hyperparameters,
    )

    lines = [f"scenarios ({SCENARIO_DIR}):"]
    for name in list_scenarios():
        s = load_scenario(name)
        lines.append(
            f"  {name:<10} {s.env_id:<28} evaluation seeds "
            f"{_seeds(s.seeds.evaluation_start, s.seeds.evaluation_count)}, validation seeds "
            f"{_seeds(s.validation_seeds.start, len(s.validation_seeds))}, training seeds "
            f"{_seeds(s.seeds.training_start, s.seeds.training_count)}"
        )
    invalid = invalid_scenarios()
    if invalid:
        lines.append("invalid scenario files (skipped; using one raises this error):")
        lines += [f"  {name:<10} {_one_line(error)}" for name, error in invalid.items()]
    lines.append(f"suites ({SUITES_DIR}):")
    for name in list_suites():
        suite, error = _try(functools.partial(load_suite, name))
        if error is not None:
            lines.append(f"  {name:<10} INVALID: {error}")
        else:
            lines.append(
                f"  {name:<10} {', '.join(suite.scenarios)}; {suite.episodes} episodes; "
                f"{len(suite.agents)} agent specs; {suite.description}"
            )
    lines.append(f"algorithm configs ({ALGO_DIR}):")
    for algo in ALGORITHMS:
        loaded, error = _try(functools.partial(load_hyperparameters, algo))
        if error is not None:
            lines.append(f"  {algo:<10} INVALID: {error}")
        else:
            hp, path = loaded
            lines.append(
                f"  {algo:<10} {path.name}: {hp['total_timesteps']} steps, {hp['n_envs']} envs"
            )
    return lines


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the exit code (0, 2 for a malformed command line, 130 or 143 for
    Ctrl-C or SIGTERM). An interrupt that the command does not handle itself (``list``, or one
    while a command's modules import) ends it with one line on stderr: "python -m
    capture_bench: interrupted", with "while starting; nothing written" before the command runs.
    """
    args = sys.argv[1:] if argv is None else list(argv)
    with sigterm_as_interrupt():
        command = None
        try:
            command = _command(args)
            return command()
        except KeyboardInterrupt as exc:
            said = (
                "interrupted while starting; nothing written" if command is None else "interrupted"
            )
            print(f"{PROG}: {said}", file=sys.stderr)
            return exit_status(exc)


def _command(args: list[str]) -> Callable[[], int]:
    """The command of the command line ``args``, its modules imported, ready to run."""
    if args and args[0] == "evaluate":
        from capture_bench.evaluation.cli import main as evaluate

        return functools.partial(evaluate, args[1:])
    if args and args[0] == "train":
        from capture_bench.training.train.command import main as train

        return functools.partial(train, args[1:])
    if args and args[0] == "tune":
        from capture_bench.training.tune.command import main as tune

        return functools.partial(tune, args[1:])
    if args and args[0] == "curves":
        from capture_bench.training.curves.command import main as curves

        return functools.partial(curves, args[1:])
    if args and args[0] == "zoo-hyperparams":
        from capture_bench.training.zoo.command import main as zoo_hyperparams

        return functools.partial(zoo_hyperparams, args[1:])
    if args and args[0] == "sweep":
        from capture_bench.training.sweep.command import main as sweep

        return functools.partial(sweep, args[1:])
    if args and args[0] == "dataset":
        from capture_bench.datasets.command import main as dataset

        return functools.partial(dataset, args[1:])
    return functools.partial(_list, args)


def _list(args: list[str]) -> int:
    """``list`` (or ``--help``, or a bad command line: one line, status 2)."""
    try:
        build_parser().parse_args(args)
    except SystemExit as exc:  # --help (0) or a bad command (2, already printed in one line)
        return int(exc.code or 0)
    print("\n".join(list_everything()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
