"""Two commits' speed, benchmark by benchmark, measured in turn on the same machine.

Each commit is checked out in a ``git worktree`` of its own in a temporary folder; each
benchmark command then runs there (that commit's own script, its package first on
``PYTHONPATH``), pinned to one core (``taskset -c 0``) with numpy's BLAS on one thread, BASE and
HEAD in turn, ``--rounds`` times (the order swapped every round, so neither always runs on a
warmer or a quieter machine). Printed for each figure: both medians, their ratio HEAD/BASE,
BASE's own spread ((max - min) / median of its rounds) and ``worse`` where HEAD's median is
worse than BASE's by more than that spread (a difference beyond BASE's own noise)::

    python benchmarks/compare_commits.py HEAD~1 HEAD
    python benchmarks/compare_commits.py main my-branch --rounds 9 --seconds 5
    python benchmarks/compare_commits.py HEAD~1 HEAD --bench env-single reset
    python benchmarks/compare_commits.py HEAD~1 HEAD \\
        --bench reset "quick=python evaluate.py --suite quick --out /tmp/quick"

``--bench`` takes names of `BENCHMARKS` (default: all of them but ``estimator``) or
``LABEL=COMMAND``: a command of its own, timed whole (wall-clock and CPU seconds of the process
and its children, start-up included). The named ones read the figures their script prints,
each table's column found by its header (`Table`), so that a commit whose script prints
other rows shows them as missing on one side rather than misread.

The figures are as good as the machine is quiet: other processes on the pinned core (a training
run, a test suite) slow both commits' rounds alike only on average, and the spread says how much.
"""

from __future__ import annotations

import argparse
import os
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Table:
    """Figures of a table a benchmark prints: the column headed ``column`` of every row under
    the first header line that has it, each row named by its first ``keys`` cells (a row may
    have more cells than the header where its name has spaces: cells are counted from the
    right), up to the first line that is not such a row.

    Attributes:
        column: the header of the figure's column.
        keys: how many leading header cells name a row.
        lower_is_better: whether a smaller figure is a faster commit.
    """

    column: str
    keys: int = 1
    lower_is_better: bool = False

    def __call__(self, output: str) -> dict[str, float]:
        lines = output.splitlines()
        start = next((i for i, line in enumerate(lines) if self.column in line.split()), None)
        if start is None:
            raise ValueError(f"no header with a {self.column!r} column")
        header = lines[start].split()
        from_right = len(header) - header.index(self.column)
        figures: dict[str, float] = {}
        for line in lines[start + 1 :]:
            cells = line.split()
            if set(line.strip()) <= {"-", " "} and line.strip():  # a rule under the header
                continue
            if len(cells) < len(header):
                break
            try:
                value = float(cells[-from_right])
            except ValueError:
                break
            name = " ".join(cells[: len(cells) - (len(header) - self.keys)])
            figures[f"{name} {self.column}"] = value
        if not figures:
            raise ValueError(f"no rows under the {self.column!r} header")
        return figures


@dataclass(frozen=True)
class Benchmark:
    """A command (run in a commit's worktree) and how to read its figures.

    Attributes:
        command: the command's words, ``{seconds}`` and ``{episodes}`` filled in.
        figures: the figures of its output (None: the process's own wall-clock and CPU seconds).
    """

    command: str
    figures: Table | None = None


BENCHMARKS: dict[str, Benchmark] = {
    "env-single": Benchmark(
        "python benchmarks/bench_env.py --scenarios paper noisy --sources ekf --seconds {seconds}",
        Table("steps/s", keys=2),
    ),
    "env-vector": Benchmark(
        "python benchmarks/bench_env.py --scenarios paper noisy --sources ekf --num-envs 64 "
        "--seconds {seconds}",
        Table("steps/s", keys=2),
    ),
    "reset": Benchmark(
        "python benchmarks/bench_reset.py --episodes {episodes} --repeats 1",
        Table("total", lower_is_better=True),
    ),
    "estimator": Benchmark(
        "python benchmarks/bench_estimator_batch.py --sizes 1 16 64",
        Table("us/env/update", lower_is_better=True),
    ),
}
DEFAULT_BENCHMARKS = ("env-single", "env-vector", "reset")
PINNED = ("taskset", "-c", "0")
#: Figures of a command timed whole: (name, lower is better).
PROCESS_FIGURES = (("wall s", True), ("cpu s", True))


def worktree(commit: str, folder: Path) -> Path:
    """A detached worktree of ``commit`` in ``folder`` (``ValueError`` naming a commit git does
    not know)."""
    done = subprocess.run(
        ["git", "worktree", "add", "--detach", str(folder), commit],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    if done.returncode:
        raise ValueError(f"cannot check out {commit!r}: {done.stderr.strip().splitlines()[-1]}")
    return folder


def describe(commit: str) -> str:
    """``abc1234 subject`` of a commit, cut to 80 characters."""
    line = subprocess.run(
        ["git", "log", "-1", "--format=%h %s", commit],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    return line if len(line) <= 80 else line[:77] + "..."


def environment(tree: Path) -> dict[str, str]:
    """The benchmarks' environment in ``tree``: its package first, one BLAS thread."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(tree), env.get("PYTHONPATH")]))
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[name] = "1"
    return env


def check_package(tree: Path) -> None:
    """``RuntimeError`` unless ``import capture_bench`` in ``tree`` finds that tree's package
    (an installed one could shadow it)."""
    found = subprocess.run(
        [sys.executable, "-c", "import capture_bench; print(capture_bench.__file__)"],
        cwd=tree,
        env=environment(tree),
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    if not Path(found).resolve().is_relative_to(tree.resolve()):
        raise RuntimeError(f"in {tree} capture_bench is imported from {found}")


def run(tree: Path, words: list[str], figures: Table | None) -> dict[str, float]:
    """One pinned run of a benchmark in ``tree``: its figures (``RuntimeError`` with the end of
    its output where it fails or prints none)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(
        [*PINNED, *words], cwd=tree, env=environment(tree), capture_output=True, text=True
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    tail = "\n".join((done.stdout + done.stderr).splitlines()[-8:])
    if done.returncode:
        raise RuntimeError(f"{' '.join(words)} exited {done.returncode} in {tree}:\n{tail}")
    if figures is None:
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return {"wall s": wall, "cpu s": cpu}
    try:
        return figures(done.stdout)
    except ValueError as error:
        raise RuntimeError(f"{' '.join(words)} in {tree}: {error}:\n{tail}") from None


def parse_bench(spec: str, seconds: float, episodes: int) -> tuple[str, list[str], Table | None]:
    """``--bench``'s ``NAME`` or ``LABEL=COMMAND`` as (label, words, figures)."""
    if "=" in spec:
        label, command = spec.split("=", 1)
        if not label.strip() or not command.strip():
            raise ValueError(f"--bench {spec!r}: give LABEL=COMMAND, both non-empty")
        return label.strip(), _python(shlex.split(command)), None
    if spec not in BENCHMARKS:
        raise ValueError(
            f"--bench {spec!r} is not one of {', '.join(BENCHMARKS)} (or LABEL=COMMAND)"
        )
    bench = BENCHMARKS[spec]
    words = shlex.split(bench.command.format(seconds=seconds, episodes=episodes))
    return spec, _python(words), bench.figures


def _python(words: list[str]) -> list[str]:
    """A command's words with ``python`` as this interpreter."""
    return [sys.executable, *words[1:]] if words[:1] == ["python"] else words


def lower_is_better(figures: Table | None, name: str) -> bool:
    """Whether a smaller value of figure ``name`` is faster."""
    if figures is None:
        return dict(PROCESS_FIGURES)[name]
    return figures.lower_is_better


def compare(
    label: str,
    figures: Table | None,
    base: list[dict[str, float]],
    head: list[dict[str, float]],
) -> list[list[str]]:
    """The table's rows of one benchmark's rounds: benchmark, figure, BASE's and HEAD's
    medians, HEAD/BASE, BASE's spread, which way is faster and ``worse`` where HEAD's median is
    worse than BASE's by more than BASE's spread (max - min)."""
    rows = []
    for name in dict.fromkeys([*base[0], *head[0]]):
        b = [r[name] for r in base if name in r]
        h = [r[name] for r in head if name in r]
        if not b or not h:
            rows.append([label, name, *(["-"] * 4), f"only in {'HEAD' if h else 'BASE'}"])
            continue
        mb, mh = statistics.median(b), statistics.median(h)
        low = lower_is_better(figures, name)
        loss = mh - mb if low else mb - mh
        worse = loss > max(b) - min(b)
        spread = (max(b) - min(b)) / mb if mb else float("nan")
        rows.append(
            [
                label,
                name,
                f"{mb:.6g}",
                f"{mh:.6g}",
                f"{mh / mb:.3f}",
                f"{spread:.1%}",
                ("lower" if low else "higher") + " is better" + ("; worse" if worse else ""),
            ]
        )
    return rows


def table(rows: list[list[str]]) -> str:
    """``rows`` under `HEADER`, each column as wide as its widest cell (text left, figures
    right)."""
    rows = [HEADER, *rows]
    widths = [max(len(row[i]) for row in rows) for i in range(len(HEADER))]
    lines = []
    for row in rows:
        cells = [
            cell.ljust(width) if i in (0, 1, 6) else cell.rjust(width)
            for i, (cell, width) in enumerate(zip(row, widths))
        ]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


HEADER = ["benchmark", "figure", "BASE median", "HEAD median", "HEAD/BASE", "BASE spread", ""]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("base", help="the commit compared against (BASE)")
    parser.add_argument("head", help="the commit measured (HEAD)")
    parser.add_argument(
        "--bench",
        nargs="+",
        default=list(DEFAULT_BENCHMARKS),
        help=f"names ({', '.join(BENCHMARKS)}) or LABEL=COMMAND",
    )
    parser.add_argument("--rounds", type=int, default=5, help="runs of each benchmark per commit")
    parser.add_argument("--seconds", type=float, default=3.0, help="bench_env's seconds a row")
    parser.add_argument("--episodes", type=int, default=200, help="bench_reset's episodes")
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.seconds <= 0 or args.episodes < 1:
        parser.error("--rounds and --episodes take whole numbers >= 1, --seconds a time > 0")
    try:
        benches = [parse_bench(spec, args.seconds, args.episodes) for spec in args.bench]
    except ValueError as error:
        parser.error(str(error))
    with tempfile.TemporaryDirectory(prefix="compare-commits-") as tmp:
        trees: dict[str, Path] = {}
        try:
            for side, commit in (("BASE", args.base), ("HEAD", args.head)):
                trees[side] = worktree(commit, Path(tmp) / side.lower())
                check_package(trees[side])
            print(f"BASE {describe(args.base)}\nHEAD {describe(args.head)}")
            print(
                f"{args.rounds} rounds, BASE and HEAD in turn, {' '.join(PINNED)}, "
                "OPENBLAS_NUM_THREADS=1"
            )
            results = {(label, side): [] for label, _, _ in benches for side in trees}
            for round_ in range(args.rounds):
                order = ("BASE", "HEAD") if round_ % 2 == 0 else ("HEAD", "BASE")
                for label, words, figures in benches:
                    for side in order:
                        results[label, side].append(run(trees[side], words, figures))
                print(f"round {round_ + 1} of {args.rounds} done", file=sys.stderr, flush=True)
            rows = []
            for label, _, figures in benches:
                rows += compare(label, figures, results[label, "BASE"], results[label, "HEAD"])
            print("\n" + table(rows))
        except (RuntimeError, ValueError) as error:
            print(f"compare_commits: {error}", file=sys.stderr)
            return 1
        finally:
            for tree in trees.values():
                subprocess.run(
                    ["git", "worktree", "remove", "--force", str(tree)],
                    cwd=ROOT,
                    capture_output=True,
                )
            subprocess.run(["git", "worktree", "prune"], cwd=ROOT, capture_output=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
