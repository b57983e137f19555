"""Evaluate agents on a leaderboard suite and write the report: capture-bench's main job.

    python evaluate.py                       # default suite: every scenario, 100 seeds, all agents
    python evaluate.py --suite quick         # smoke run
    python evaluate.py --agents incremental_ik models/dagger-dls-paper --scenarios paper
    python evaluate.py --scenarios path/to/my_scenario.yaml --suite quick
    python evaluate.py --workers 1           # serially, in this process (default: every CPU)
    python evaluate.py --suite quick --video videos/   # also a GIF of each agent's first episode
    python evaluate.py --backend ray --ray-address auto
    python evaluate.py --merge reports/custom-1 reports/custom-2   # reports of several machines

Writes ``<out>/<suite>/`` (leaderboard.md/.html, results.csv/.json, episodes.csv, figures;
``reports/`` by default, git-ignored), replacing the previous report only once the new one is
complete, and ends by comparing it with the published report of the same suite,
``reports/published/<suite>/``, value by value (printed, and written beside the report as
``reproduction.md``/``.json``: `capture_bench.evaluation.reporting.reproduction`). Only
``--publish`` writes the published report (a shipped suite as defined, on the published seeds),
and no output option may point inside it otherwise; with the suite's ``videos`` (the
default) its "Episodes to watch" show the reference and the best-ranked trained model on one seed
of each scenario as GIFs. ``--agents``, ``--scenarios`` or
``--episodes`` that change the suite make a custom selection, written to
``<out>/custom-<hash of the selection>/``, and so does a suite file named like a shipped suite
that is not it (``--suite my/default.yaml``): ``reports/<suite>/`` only ever holds that suite as
defined; the output names the folder written. Bad input (unknown agent, scenario or suite, a
missing, corrupt or untrusted model, mismatched spaces, an output folder that cannot be written,
an empty option value) prints one line to stderr and exits with code 2, before any episode runs
or any file is written. Ctrl-C (SIGINT) or SIGTERM stops every worker and exits with 130 or 143
and one line saying what is on disk: no report written (the previous report as it was), or, once
the new report is in place, the report written (a signal while it replaces the previous one lands
just after; `main`). The summary table printed at the end
fits the terminal (80 columns in a pipe or a CI log: then without the per-scenario columns).
Models load without unpickling anything (``--trust-model`` to allow an SB3 ``.zip``).
``--merge DIR DIR ...`` plays no episode: it merges finished reports into
``<out>/merged-<hash>/`` once they are checked to be mergeable
(`capture_bench.evaluation.reporting.merge`), or refuses in one line.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import shlex
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from capture_bench.argparsing import OneLineParser, program
from capture_bench.evaluation.pipeline import (
    INPUT_ERRORS,
    EvaluationConfig,
    Plan,
    plan_evaluation,
    run_evaluation,
)
from capture_bench.evaluation.reporting import reproduction
from capture_bench.evaluation.reporting.aggregate import RankingRow
from capture_bench.evaluation.reporting.merge import plan_merge
from capture_bench.evaluation.reporting.report import ReportData, write_report
from capture_bench.evaluation.reporting.reproduction import (
    PublishedReport,
    as_json,
    compare,
    markdown,
    read_published,
    summary_lines,
)
from capture_bench.evaluation.running.backends import BACKENDS, prestart_workers
from capture_bench.evaluation.running.suites import ALL, SEED_SETS, shadowed_suite
from capture_bench.files import atomic_write
from capture_bench.interrupts import exit_status, sigterm_as_interrupt
from capture_bench.progress import episode_bar
from capture_bench.provenance import display_path, git_state
from capture_bench.task.scenarios import invalid_scenarios

if TYPE_CHECKING:
    from rich.table import Table

#: The script's name; the console script shows its own (`capture_bench.argparsing.program`).
PROG = "evaluate.py"


def _epilog() -> str:
    """Examples, and what is valid: the built-in agents, shipped models, scenarios, suites and
    the algorithms train.py trains (a broken file is left out here; ``python -m capture_bench
    list`` names it and its error)."""
    from capture_bench.agents.algorithms import ALGORITHMS
    from capture_bench.evaluation.running.agents_loading import builtin_names
    from capture_bench.evaluation.running.suites import list_suites
    from capture_bench.paths import models_dir
    from capture_bench.task.scenarios import list_scenarios

    models = sorted(
        f"models/{p.name}" for p in models_dir().glob("*") if (p / "metadata.json").is_file()
    )
    return "\n".join([
        "examples:",
        "  python evaluate.py                                   # default suite, vs the published",
        "  python evaluate.py --publish                         # rewrite reports/published/",
        "  python evaluate.py --suite quick                     # a smoke run",
        "  python evaluate.py --agents incremental_ik models/dagger-dls-paper --scenarios paper",
        "  python evaluate.py --agents runs/paper-ppo-0/best --episodes 20 --workers 2",
        "  python evaluate.py --agents my_agents:MyController   # your own class",
        "  python evaluate.py --agents models/dagger-dls-paper --scenarios paper --episodes 5 \\",
        "      --video videos/ --video-episodes 2               # GIFs of the first 2 episodes",
        "  python evaluate.py --merge reports/custom-a reports/custom-b   # merge finished reports",
        "",
        f"built-in agents: {', '.join(builtin_names())}",
        f"shipped models:  {', '.join(models) or 'none'}",
        f"scenarios:       {', '.join(list_scenarios())}",
        f"suites:          {', '.join(list_suites())}",
        f"algorithms (train.py): {', '.join(ALGORITHMS)}",
        "",
        "Everything installed, and any broken file with its error: python -m capture_bench list",
    ])  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    """The command-line options (each maps to a field of ``EvaluationConfig``)."""
    parser = OneLineParser(
        prog=PROG,
        hint=" (see --help)",
        description=__doc__.splitlines()[0],
        epilog=_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--suite",
        help="suite name in configs/suites/ or a suite YAML path (default: default)",
    )
    parser.add_argument(
        "--agents",
        nargs="+",
        metavar="AGENT",
        help="agents replacing the suite's: built-in names, model directories "
        "(models/<name>, run dirs), module:Class; comma or space separated",
    )
    parser.add_argument(
        "--scenarios",
        nargs="+",
        metavar="SCENARIO",
        help="scenarios replacing the suite's (comma or space separated)",
    )
    parser.add_argument(
        "--episodes",
        type=int,
        help="episodes per agent x scenario: the first N seeds of the seed set",
    )
    parser.add_argument(
        "--seed-set",
        choices=SEED_SETS,
        default="evaluation",
        help="the seeds to play: the published evaluation seeds (the leaderboard), or the "
        "scenarios' validation seeds, to select and compare models without a published seed "
        "(report in OUT/<suite>-validation/) (default: evaluation)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        help="local worker processes (default: every usable CPU; 1 runs serially in this process)",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        help="where episodes run (default: process if more than one worker, else serial)",
    )
    parser.add_argument("--ray-address", help="Ray cluster address for --backend ray")
    parser.add_argument(
        "--out",
        type=Path,
        help="report root; the report goes to OUT/<suite>/ (default reports/, git-ignored); "
        "never inside reports/published/",
    )
    parser.add_argument(
        "--publish",
        action="store_true",
        help="write the published leaderboard, reports/published/<suite>/ (committed; what "
        "README's table is read from): only a shipped suite as defined, on the published seeds",
    )
    parser.add_argument(
        "--episode-plots",
        type=Path,
        metavar="DIR",
        help="also plot the first episode of every agent x scenario into DIR",
    )
    parser.add_argument(
        "--video",
        type=Path,
        metavar="DIR",
        help="also record the first episode(s) of every agent x scenario as animated GIFs "
        "(pybullet frames with the target's and end-effector's traces) into DIR, named "
        "<agent>_<scenario>_seed<seed>.gif: the same episodes as in episodes.csv",
    )
    parser.add_argument(
        "--video-episodes",
        type=int,
        metavar="K",
        help="with --video: the first K seeds of each agent x scenario (default 1)",
    )
    parser.add_argument(
        "--trust-model",
        action="store_true",
        help="load a model directory that has no safe policy.pt from its SB3 .zip; a .zip holds "
        "pickled Python objects, which can run code when loaded: only for models you trust",
    )
    parser.add_argument(
        "--merge",
        nargs="+",
        type=Path,
        metavar="DIR",
        help="merge reports written by evaluate.py (e.g. one agent per machine) into one, "
        "OUT/merged-<hash>/, once they are checked to have played the same scenario files, seeds "
        "and code; plays no episode (only --out applies)",
    )
    return parser


#: The options that choose or play episodes, which ``--merge`` (no episode played) refuses.
EPISODE_OPTIONS = (
    "--publish",
    "--suite",
    "--agents",
    "--scenarios",
    "--episodes",
    "--workers",
    "--backend",
    "--ray-address",
    "--episode-plots",
    "--video",
    "--video-episodes",
    "--trust-model",
)


def _split(values: list[str] | None) -> list[str] | None:
    if values is None:
        return None
    return [item for value in values for item in value.split(",") if item]


def parse_arguments(argv: list[str]) -> argparse.Namespace:
    """Parse the command line, refusing options that do not go together."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.video_episodes is not None and args.video is None:
        parser.error(
            f"--video-episodes {args.video_episodes} records episodes only with --video DIR; "
            "add --video DIR (the folder for the GIFs) or drop --video-episodes"
        )
    if args.merge is not None:
        given = [
            o
            for o in EPISODE_OPTIONS
            if getattr(args, o[2:].replace("-", "_")) not in (None, False)
        ]
        if given:
            parser.error(
                f"--merge combines finished reports and plays no episode, so {given[0]} does "
                "not apply; drop it (--out is the one option --merge takes)"
            )
    return args


def parse_config(argv: list[str]) -> EvaluationConfig:
    """Parse the command line into a typed config."""
    return evaluation_config(parse_arguments(argv))


def evaluation_config(args: argparse.Namespace) -> EvaluationConfig:
    """The typed config of parsed options (not ``--merge``)."""
    return EvaluationConfig(
        suite="default" if args.suite is None else args.suite,
        agents=_split(args.agents),
        scenarios=_split(args.scenarios),
        episodes=args.episodes,
        seed_set=args.seed_set,
        backend=args.backend,
        workers=args.workers,
        ray_address=args.ray_address,
        out=_out(args),
        episode_plots=args.episode_plots,
        video=args.video,
        video_episodes=1 if args.video_episodes is None else args.video_episodes,
        trust_model=args.trust_model,
        publish=args.publish,
    )


def _out(args: argparse.Namespace) -> Path:
    """The report root: ``--out``, else the published folder with ``--publish``, else
    ``reports/`` (a ``--publish`` with an ``--out`` of its own is refused when planned)."""
    if args.out is not None:
        return args.out
    return reproduction.published_dir() if args.publish else Path("reports")


SUMMARY_CAPTION = (
    "ratio: mean over scenarios of the median capture time / physical limit; "
    "speed: mean over scenarios of the median relative speed at capture, mm/s"
)


def summary_table(
    suite: str,
    ranking: Sequence[RankingRow],
    rates: Mapping[tuple[str, str], float],
    width: int,
) -> Table:
    """The ranking as the terminal shows it: rank, agent, mean capture rate (%), the rate on
    each scenario (%), ratio and speed, ``width`` columns wide at most.

    ``rates`` maps (agent, scenario) to the capture rate, scenarios in report order. Where the
    scenario columns do not fit in ``width`` (16 agents on 8 scenarios need ~100 columns; a pipe
    or a CI log gets 80), they are left out, so that no agent name, rate or ratio is cut short;
    the caption then says where they are.
    """
    from rich.console import Console
    from rich.measure import Measurement

    scenarios = list(dict.fromkeys(scenario for _, scenario in rates))
    table = _table(suite, ranking, rates, scenarios)
    unbounded = Console(width=10_000, file=io.StringIO())  # measures the table's natural width
    if Measurement.get(unbounded, unbounded.options, table).maximum > width:
        table = _table(suite, ranking, rates, [])
        table.caption = f"{SUMMARY_CAPTION}. Per scenario: the report (leaderboard.md)."
    return table


def _table(
    suite: str,
    ranking: Sequence[RankingRow],
    rates: Mapping[tuple[str, str], float],
    scenarios: list[str],
) -> Table:
    from rich.table import Table

    table = Table(
        title=f"capture-bench · {suite} · capture rate, % of episodes",
        caption=SUMMARY_CAPTION,
    )
    table.add_column("rank", justify="right", no_wrap=True)
    table.add_column("agent", no_wrap=True)
    for column in ("mean", *scenarios, "ratio", "speed"):
        table.add_column(column, justify="right", no_wrap=True)
    for row in ranking:
        table.add_row(
            "—" if row.rank is None else str(row.rank),
            row.agent + (" (privileged)" if row.privileged else ""),
            f"{100 * row.mean_capture_rate:.0f}",
            *(f"{100 * rates.get((row.agent, s), math.nan):.0f}" for s in scenarios),
            f"{row.mean_ratio_median:.2f}",
            "—"
            if math.isnan(row.mean_relative_speed_median)
            else f"{1e3 * row.mean_relative_speed_median:.0f}",
        )
    return table


def _print_summary(data: ReportData, target: Path) -> None:
    from rich.console import Console

    console = Console()
    rates = {(s.agent, s.scenario): s.capture_rate.value for s in data.summaries}
    console.print(summary_table(data.suite, data.ranking, rates, console.width))
    console.print(f"report: {target}")


def _run(plan: Plan, config: EvaluationConfig, command: str) -> tuple[ReportData, Path]:
    total = len(plan.tasks) + len(plan.seed_tasks) + len(plan.twin_tasks)  # seeds, twins too
    bar, task = episode_bar(plan.report_name, total)
    with bar:
        return run_evaluation(plan, config, command, lambda n: bar.advance(task, n))


def _where_note(config: EvaluationConfig, plan: Plan) -> str | None:
    """Why the report goes to a folder other than ``<out>/<suite>/``, and where; None if not."""
    target = config.out / plan.report_name
    if plan.seed_set != "evaluation":
        return (
            f"validation seeds, so the report goes to {target}/ (the leaderboard's reports are "
            "left as they are)"
        )
    shadowed = shadowed_suite(config.suite)
    if shadowed is not None:
        return (
            f"{config.suite} is not the shipped {shadowed!r} suite, so the report goes to "
            f"{target}/ ({config.out / shadowed}/ is left as it is)"
        )
    if plan.suite.name != config.suite and plan.suite.name.startswith("custom-"):
        return (
            f"a custom selection, so the report goes to {target}/ (the {config.suite!r} "
            "suite's own report is left as it is)"
        )
    return None


def _refuse(prog: str, exc: Exception) -> int:
    """Bad input: one line on stderr; the exit status 2."""
    message = " ".join(str(exc).split())
    print(f"{prog}: error: {message}", file=sys.stderr)
    return 2


def _merge(directories: list[Path], out: Path, command: str, prog: str) -> int:
    """``--merge``: check the reports, then write their merged report into ``out``."""
    try:
        data, notes = plan_merge(directories, out, command)
    except INPUT_ERRORS as exc:
        return _refuse(prog, exc)
    for note in notes:
        print(f"{prog}: note: {note}", file=sys.stderr)
    _print_summary(data, write_report(data, out))
    return 0


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    prog = program(PROG)
    try:
        args = parse_arguments(argv)
    except SystemExit as exc:  # --help, or a malformed option (already reported in one line)
        return int(exc.code or 0)
    command = " ".join(["python", PROG, *(shlex.quote(a) for a in argv)])
    if args.merge is not None:
        return _merge(args.merge, _out(args), command, prog)
    config = evaluation_config(args)
    try:
        if config.resolved_backend() == "process":
            prestart_workers()  # the workers' imports while this process plans
        plan = plan_evaluation(config)
    except INPUT_ERRORS as exc:
        return _refuse(prog, exc)
    if plan.suite.scenarios == (ALL,):  # "every scenario": say which invalid files were left out
        for name, error in invalid_scenarios().items():
            print(f"{prog}: note: skipping invalid scenario {name!r}: {error}", file=sys.stderr)
    if git_state().get("dirty"):
        print(
            f"{prog}: note: the checkout has uncommitted changes; results.json will say "
            "dirty: true (commit first for a report others can trace to its code)",
            file=sys.stderr,
        )
    where = _where_note(config, plan)
    if where is not None:
        print(f"{prog}: note: {where}", file=sys.stderr)
    published_folder = reproduction.published_dir() / plan.report_name
    published = read_published(published_folder)  # before a --publish replaces it
    if published is None and (published_folder / "results.json").is_file():
        print(
            f"{prog}: note: {display_path(published_folder)} cannot be read as a report of this "
            "code's (made by other code?); the run is not compared with it",
            file=sys.stderr,
        )
    data, target = _run(plan, config, command)
    _print_summary(data, target)
    _compare_with_published(published, target, config.publish, prog)
    return 0


def _compare_with_published(
    published: PublishedReport | None, target: Path, publishing: bool, prog: str
) -> None:
    """The run beside the published report of its suite (the previous one, with
    ``--publish``): printed, and written into the run's report as ``reproduction.md`` and
    ``reproduction.json`` (the published folder gets nothing beyond its report)."""
    if published is None:
        return
    run = read_published(target)
    if run is None:  # the report just written cannot be read back: say so, change nothing
        print(f"{prog}: note: {target} could not be read back to compare", file=sys.stderr)
        return
    name = display_path(published.directory) + ("/ (before this run)" if publishing else "/")
    comparison = compare(run, published, published_name=name)
    for line in summary_lines(comparison):
        print(line)
    if not publishing:
        atomic_write(target / "reproduction.md", markdown(comparison).encode())
        text = json.dumps(as_json(comparison), indent=2, allow_nan=False) + "\n"
        atomic_write(target / "reproduction.json", text.encode())


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 done, 2 bad input, 130/143 interrupted). An
    interrupt's one line says what is on disk: no report written (a previous one as it was), or
    the report folder written before it came (an interrupt during the replacement lands once the
    new report is in place: `write_report`)."""
    from capture_bench.evaluation.reporting.report import reports_written

    with sigterm_as_interrupt(), reports_written() as written:
        try:
            return _main(argv)
        except KeyboardInterrupt as exc:
            said = (
                f"interrupted after the report was written to {written[-1]}/"
                if written
                else "interrupted; no report written (a previous report is as it was)"
            )
            print(f"{program(PROG)}: {said}", file=sys.stderr)
            return exit_status(exc)


if __name__ == "__main__":
    raise SystemExit(main())
