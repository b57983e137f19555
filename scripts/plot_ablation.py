"""Plot an ablation: validation capture rate and median ratio to the physical limit against
environment steps for several train.py runs (their ``validations.csv``), one line each.

    python scripts/plot_ablation.py --out docs/figures/ablation_ppo_paper.png \
        dense=runs/ablation/dense features=runs/ablation/features ...

Each ``LABEL=PATH`` is a train.py run directory or a ``validations.csv`` itself, such as the
copies committed under ``docs/ablation/`` (``dense=docs/ablation/ppo_paper_dense.csv``). The figure
is written whole or not at all, in the format its suffix names (``.png``, ``.pdf``, ``.svg``, ...).

The runs of README's "Learning the last millimetre" were made with (at commit 0cde12e):

    python train.py --algo ppo --scenario paper --total-timesteps 300000 --set eval_freq=30000 \
        --set eval_episodes=20 --set checkpoint_freq=100000 --run-dir runs/ablation/<name> <lever>

with <lever> empty (dense), ``--reward shaped``, ``--set
policy_kwargs.features_extractor=relative_log_distance``, or both.
"""

from __future__ import annotations

import csv
import sys
from dataclasses import dataclass
from pathlib import Path

from capture_bench.argparsing import OneLineParser
from capture_bench.files import atomic_write, check_writable
from capture_bench.task.scenarios import ConfigError
from capture_bench.training.common.policy_export import VALIDATIONS_FILE

#: The columns of ``validations.csv`` the figure draws.
COLUMNS = ("step", "capture_rate", "median_ratio_to_limit")
_RUN_FORM = (
    "expected LABEL=PATH, e.g. dense=runs/ablation/dense "
    f"(a train.py run directory or its {VALIDATIONS_FILE})"
)


@dataclass(frozen=True)
class Curve:
    """One run's validations: environment steps, capture rate (0..1) and median ratio of capture
    time to the physical limit (NaN where no episode was captured), one entry per validation."""

    label: str
    steps: list[int]
    capture_rate: list[float]
    median_ratio_to_limit: list[float]


def parse_run(item: str) -> tuple[str, Path]:
    """``LABEL=PATH`` -> (label, path); [`ConfigError`][capture_bench.ConfigError] for anything
    else."""
    label, sep, path = item.partition("=")
    if not sep or not label.strip() or not path.strip():
        raise ConfigError(f"run {item!r}: {_RUN_FORM}")
    return label, Path(path)


def read_curve(label: str, path: Path) -> Curve:
    """The validations of the run at ``path`` (a run directory or a ``validations.csv``).

    Raises:
        ConfigError: no such path, a run without validations, or a file that is not a
            ``validations.csv`` (naming the file, the row and the column).
    """
    if not path.exists():
        raise ConfigError(f"{label}={path}: no such run directory or file; {_RUN_FORM}")
    csv_file = path / VALIDATIONS_FILE if path.is_dir() else path
    if not csv_file.is_file():
        raise ConfigError(
            f"{path}: no {VALIDATIONS_FILE}; train.py writes it only with periodic validation "
            "(--set eval_freq=N, N > 0)"
        )
    wanted = f"a train.py {VALIDATIONS_FILE} with columns {', '.join(COLUMNS)}"
    try:
        with open(csv_file, newline="") as handle:
            rows = list(csv.DictReader(handle))
    except (OSError, ValueError, csv.Error) as exc:  # UnicodeDecodeError is a ValueError
        reason = getattr(exc, "strerror", None) or " ".join(str(exc).split())[:80]
        raise ConfigError(f"{csv_file}: cannot be read ({reason}); expected {wanted}") from None
    missing = [c for c in COLUMNS if not rows or c not in rows[0]]
    if missing:
        found = "no rows" if not rows else f"no column {', '.join(missing)}"
        raise ConfigError(f"{csv_file}: {found}; expected {wanted}")
    columns: dict[str, list] = {c: [] for c in COLUMNS}
    for line, row in enumerate(rows, start=2):  # line 1 is the header
        for column in COLUMNS:
            try:
                value = int(row[column]) if column == "step" else float(row[column])
            except (TypeError, ValueError):
                valid = "an integer" if column == "step" else "a number (nan where undefined)"
                raise ConfigError(
                    f"{csv_file}: line {line}: column {column!r} is {row[column]!r}; valid: {valid}"
                ) from None
            columns[column].append(value)
    return Curve(label, columns["step"], columns["capture_rate"], columns["median_ratio_to_limit"])


def check_out(out: Path) -> str:
    """The image format of ``--out`` (its suffix); [`ConfigError`][capture_bench.ConfigError] unless
    it is a format
    matplotlib writes and a file that can be created."""
    from matplotlib.backend_bases import FigureCanvasBase

    if out.is_dir():
        raise ConfigError(f"--out {out}: a directory; give an image file, e.g. {out}/ablation.png")
    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = out.suffix.lower().lstrip(".")
    if suffix not in formats:
        valid = ", ".join(f".{name}" for name in sorted(formats))
        found = f"unknown image suffix {out.suffix!r}" if out.suffix else "no image suffix"
        raise ConfigError(f"--out {out}: {found}; valid: {valid}")
    check_writable(out.parent, "--out")
    return suffix


def write_figure(curves: list[Curve], out: Path, image_format: str) -> None:
    """Draw the two panels and write them to ``out`` atomically (parents created)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 3.8), layout="constrained")
    axes = fig.subplots(1, 2)
    for curve in curves:
        axes[0].plot(curve.steps, curve.capture_rate, marker="o", label=curve.label)
        axes[1].plot(curve.steps, curve.median_ratio_to_limit, marker="o")
    axes[0].set_ylabel("validation capture rate")
    axes[1].set_ylabel("median ratio to the physical limit")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    axes[0].legend()
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out, writer=lambda tmp: fig.savefig(tmp, format=image_format, dpi=100))


def main(argv: list[str] | None = None) -> int:
    """Plot the runs of ``argv``; returns the exit status (2: bad input, one line on stderr)."""
    parser = OneLineParser(
        prog="plot_ablation.py", description=" ".join(__doc__.split("\n\n")[0].split())
    )
    parser.add_argument("runs", nargs="+", metavar="LABEL=PATH", help=_RUN_FORM)
    parser.add_argument("--out", required=True, type=Path, help="the figure (.png, .pdf, .svg)")
    args = parser.parse_args(argv)
    try:
        runs = [parse_run(item) for item in args.runs]
        labels = [label for label, _ in runs]
        twice = sorted({label for label in labels if labels.count(label) > 1})
        if twice:
            raise ConfigError(f"label {twice[0]!r} is given twice; give each run its own label")
        image_format = check_out(args.out)
        curves = [read_curve(label, path) for label, path in runs]
    except ConfigError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    try:
        write_figure(curves, args.out, image_format)
    except OSError as exc:
        print(f"{parser.prog}: error: --out {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
