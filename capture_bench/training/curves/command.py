"""Learning curves: ``python -m capture_bench curves``.

Trains (with ``--train``) or reads runs of each algorithm on one scenario from several training
seeds, and writes one report page, ``learning_curves.md`` and a self-contained
``learning_curves.html``, with ``learning_curves.png`` and the numbers in ``curves.json``:

* validation capture rate and median ratio to the physical limit against environment steps and
  against wall-clock training time, the mean over seeds with a 95% interval (Student's t over
  the seeds: mean +- t(0.975, n-1) s / sqrt(n)), and ``incremental_ik``'s level on the same
  validation seeds drawn as a line;
* "time to baseline": per algorithm, the environment steps and the wall-clock time at which each
  seed's validation capture rate first reached ``incremental_ik``'s (median over the seeds that
  did, and how many did);
* aggregate statistics over the training seeds (rliable,
  `capture_bench.training.curves.seed_statistics`): per algorithm the IQM, optimality gap and mean
  of the runs' final mean per-episode score with stratified bootstrap intervals, and the
  probability of improvement between algorithms; the unit of replication is the training seed;
  and their performance profiles, ``performance_profile.png`` (the share of an algorithm's
  runs whose final score exceeds each threshold, with rliable's band), where an algorithm has
  two seeds or more with scores;
* the machine the runs were measured on.

With ``--pixels`` each algorithm has a second arm, ``<algo>-pixels``: the same algorithm trained
on the camera's pixels (``--observation-source pixels --config configs/pixels/<algo>.yaml``), its
runs validated on the same seeds, so the page draws the pixel-fed and the estimate-fed curves
side by side.

``--scenario`` may name a mixture (``all``, or ``a,b,c``: the runs of ``train.py --scenario
all``), whose runs validate on every scenario's first validation seeds pooled; ``incremental_ik``'s
level is then pooled the same way. ``--arms`` reads runs of any name instead of the algorithms'
(``<runs>/<scenario>-<arm>-<seed>``, e.g. ``ppo ppo-hold ppo-weighted`` for an ablation of
training recipes trained by their own commands).

Every number comes from the runs' ``validations.csv`` (written by train.py's periodic
validation: `capture_bench.training.common.policy_export.VALIDATIONS_FILE`) and, for a run that
imitated a controller first, its ``imitation.json`` (the policy validated after each DAgger
round: the curve starts there, and the algorithm's steps follow the imitation's), so the page is
regenerated without training again. Validation seeds only: nothing here reads a published
evaluation seed. Wall-clock time is the run's training time including its validations.
"""

from __future__ import annotations

import argparse
import base64
import csv
import io
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from capture_bench import rliable_stats
from capture_bench.argparsing import OneLineParser
from capture_bench.files import atomic_write, check_writable
from capture_bench.task.scenarios import ConfigError
from capture_bench.training.common import run_plan
from capture_bench.training.common.mixture import mixture_name, mixture_scenarios
from capture_bench.training.common.policy_export import IMITATION_FILE, VALIDATIONS_FILE
from capture_bench.training.common.run_plan import is_finished, run_path, train_argv
from capture_bench.training.curves import seed_statistics

METRICS = (
    ("capture_rate", "validation capture rate"),
    ("median_ratio_to_limit", "median ratio to the physical limit"),
)
#: A run's mean per-episode score at each validation (a file without the column: 0 where the
#: validation captured nothing, else NaN).
SCORE = "mean_score"
REPORT = "learning_curves"
PROFILE = "performance_profile"  # the profile's PNG, beside the curves'
PROFILE_KEYS = ("taus", "share", "low", "high")


@dataclass
class Curve:
    """One run's validations: steps, wall-clock s, and each metric and `SCORE` (NaN where
    undefined or not recorded)."""

    algo: str
    seed: int
    steps: np.ndarray
    wall: np.ndarray
    values: dict[str, np.ndarray]
    episodes: int


def read_curve(run_dir: Path, algo: str, seed: int) -> Curve:
    """A run's ``validations.csv`` (the last row of a step repeated by a resume wins).

    Raises:
        ConfigError: no such file, or one without validations or the columns it needs.
    """
    path = run_dir / VALIDATIONS_FILE
    try:
        rows = list(csv.DictReader(path.open()))
    except OSError as exc:
        raise ConfigError(
            f"{path}: cannot be read ({exc.strerror or exc}); train the run first (--train) "
            "with eval_freq > 0"
        ) from None
    need = {"step", "wall_time_s", *(m for m, _ in METRICS)}
    if not rows or not need <= set(rows[0]):
        raise ConfigError(f"{path}: no validation rows with columns {', '.join(sorted(need))}")
    by_step = {int(r["step"]): r for r in rows}
    steps = sorted(by_step)

    def column(name: str) -> np.ndarray:
        return np.array([_number(by_step[s].get(name)) for s in steps])

    saved = json.loads((run_dir / "config.json").read_text())
    episodes = int(saved["hyperparameters"]["eval_episodes"])
    values = {m: column(m) for m, _ in METRICS}
    curve = Curve(
        algo,
        seed,
        np.array(steps),
        column("wall_time_s"),
        {**values, SCORE: _scores(column(SCORE), values["capture_rate"])},
        episodes,
    )
    return _with_imitation(curve, run_dir / IMITATION_FILE)


def _with_imitation(curve: Curve, path: Path) -> Curve:
    """``curve`` of a run that imitated first (``path``, its ``imitation.json``): the policy's
    validation after each DAgger round, at the environment steps the imitation had played, then
    the algorithm's validations shifted by all of the imitation's steps (its step 0 is the
    imitation's last policy, so the last round's own point gives way to it; a file that records
    no validations shifts the algorithm's alone). Without the file, ``curve`` as it is."""
    try:
        done = json.loads(path.read_text())
        total = int(done["environment_steps"])
        rounds = done.get("validations", [])
    except (OSError, ValueError, KeyError, TypeError):
        return curve
    rounds = [v for v in rounds if int(v["environment_steps"]) < total + curve.steps[0]]

    def each(key: str) -> np.ndarray:
        return np.array([math.nan if v.get(key) is None else float(v[key]) for v in rounds])

    return Curve(
        curve.algo,
        curve.seed,
        np.concatenate([[int(v["environment_steps"]) for v in rounds], total + curve.steps]).astype(
            int
        ),
        np.concatenate([each("wall_time_s"), curve.wall]),
        {k: np.concatenate([each(k), v]) for k, v in curve.values.items()},
        curve.episodes,
    )


def _scores(recorded: np.ndarray, capture_rate: np.ndarray) -> np.ndarray:
    """Each validation's mean per-episode score: as recorded, and where a run's file predates
    the column, 0 for a validation that captured nothing (every episode a failure, each scoring
    0); NaN for the others."""
    return np.where(np.isnan(recorded) & (capture_rate == 0.0), 0.0, recorded)


def _number(text: str | None) -> float:
    try:
        return float(text) if text not in (None, "") else math.nan
    except ValueError:
        return math.nan


def mean_interval(samples: np.ndarray) -> tuple[float, float, float, int]:
    """(mean, low, high, n) of the finite samples: Student's t 95% interval over them (the
    interval is the mean itself for one sample; NaNs for none)."""
    from scipy import stats

    x = samples[np.isfinite(samples)]
    n = int(x.size)
    if n == 0:
        return math.nan, math.nan, math.nan, 0
    mean = float(x.mean())
    if n == 1:
        return mean, mean, mean, 1
    half = float(stats.t.ppf(0.975, n - 1) * x.std(ddof=1) / math.sqrt(n))
    return mean, mean - half, mean + half, n


def baseline_level(scenario: str, episodes: int) -> dict[str, float]:
    """``incremental_ik``'s validation statistics on the first ``episodes`` validation seeds of
    ``scenario`` (of each scenario of a mixture, pooled), as train.py's validation computes
    them."""
    from capture_bench.agents.incremental_ik import IncrementalIK
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.training.common.episode_stats import summarize
    from capture_bench.training.common.validation_run import run_validation

    played = []
    for sc in mixture_scenarios(scenario):
        seeds = list(sc.validation_seeds[:episodes])
        env = CaptureVectorEnv(len(seeds), sc)
        try:
            played += run_validation(IncrementalIK(env.description), env, seeds)
        finally:
            env.close()
    return summarize(played)


def final_scores(curves: dict[str, list[Curve]]) -> dict[str, dict[int, float]]:
    """``{algorithm: {training seed: the mean per-episode score of its last validation}}`` (NaN
    where the run's validations.csv has none)."""
    return {
        algo: {c.seed: float(c.values[SCORE][-1]) if c.steps.size else math.nan for c in cs}
        for algo, cs in curves.items()
    }


def time_to_baseline(curve: Curve, level: float) -> tuple[int, float] | None:
    """(steps, wall-clock s) of the first validation whose capture rate reached ``level``."""
    reached = np.flatnonzero(curve.values["capture_rate"] >= level - 1e-12)
    if not reached.size:
        return None
    i = int(reached[0])
    return int(curve.steps[i]), float(curve.wall[i])


def aggregate(curves: list[Curve]) -> dict[str, Any]:
    """Per validation step common to every seed: mean and interval of each metric, and the mean
    wall-clock time."""
    common = sorted(set.intersection(*(set(c.steps.tolist()) for c in curves)))
    out: dict[str, Any] = {"steps": common, "wall_s": []}
    for metric, _ in METRICS:
        out[metric] = {"mean": [], "low": [], "high": [], "n": []}
    for step in common:
        rows = [int(np.flatnonzero(c.steps == step)[0]) for c in curves]
        out["wall_s"].append(float(np.mean([c.wall[i] for c, i in zip(curves, rows)])))
        for metric, _ in METRICS:
            mean, low, high, n = mean_interval(
                np.array([c.values[metric][i] for c, i in zip(curves, rows)])
            )
            if metric == "capture_rate" and n:
                low, high = max(low, 0.0), min(high, 1.0)
            for key, value in zip(("mean", "low", "high", "n"), (mean, low, high, n)):
                out[metric][key].append(value)
    return out


def figure(
    curves: dict[str, list[Curve]], summary: dict[str, Any], baseline: dict[str, float]
) -> bytes:
    """The 2 x 2 plot (metric x steps / wall-clock) as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), constrained_layout=True)
    colours = plt.get_cmap("tab10")
    for row, (metric, label) in enumerate(METRICS):
        for col, (axis_key, xlabel) in enumerate(
            (("steps", "environment steps"), ("wall_s", "wall-clock training time, s"))
        ):
            ax = axes[row][col]
            for k, algo in enumerate(curves):
                agg = summary[algo]
                x = np.array(agg[axis_key], dtype=float)
                m = agg[metric]
                mean, low, high = (np.array(m[key], dtype=float) for key in ("mean", "low", "high"))
                n = len(curves[algo])
                ax.plot(x, mean, color=colours(k), label=f"{algo.upper()} ({n} seeds)")
                ax.fill_between(x, low, high, color=colours(k), alpha=0.2, linewidth=0)
            level = baseline[metric]
            if math.isfinite(level):
                ax.axhline(
                    level,
                    color="black",
                    linestyle="--",
                    linewidth=1,
                    label=f"incremental_ik ({level:.2f})",
                )
            ax.set_xlabel(xlabel)
            ax.set_ylabel(label)
            if metric == "median_ratio_to_limit":
                ax.set_yscale("log")
            else:
                ax.set_ylim(-0.02, 1.02)
            ax.grid(alpha=0.3)
    axes[0][0].legend(loc="lower right", fontsize=8)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return buffer.getvalue()


def profile_figure(profiles: dict[str, dict[str, list[float]]]) -> bytes:
    """The performance profiles over training seeds (``seed_statistics.compute``'s
    ``performance_profiles``: per algorithm the share of its runs whose final score exceeds each
    tau, with rliable's band) as PNG bytes, in the learning curves' colours."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cmap = plt.get_cmap("tab10")
    curves = {
        algo.upper(): rliable_stats.Profile(*(np.array(p[k]) for k in PROFILE_KEYS))
        for algo, p in profiles.items()
    }
    fig, ax = plt.subplots(figsize=(9, 4.5), constrained_layout=True)
    rliable_stats.draw_profiles(
        ax, curves, {a: cmap(k) for k, a in enumerate(curves)}, None, "runs"
    )
    ax.set_title("Performance profile (rliable): final validation score of each training seed")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return buffer.getvalue()


def _format_time(seconds: float) -> str:
    """Seconds in words; an imitation round of a run that did not record its wall clock: '-'."""
    if math.isnan(seconds):
        return "-"
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def report(  # noqa: PLR0913
    runs: Path,
    out: Path,
    scenario: str,
    algos: list[str],
    seeds: list[int],
    command: str,
    present_only: bool = False,
) -> Path:
    """Write the report page from the runs in ``runs``; return the markdown file.
    ``present_only``: each arm reads those of ``seeds`` whose run exists (at least one)."""
    from capture_bench.provenance import git_state, machine

    name = mixture_name(scenario)
    chosen = {
        a: [s for s in seeds if not present_only or run_path(runs, name, a, s).is_dir()]
        for a in algos
    }
    for a, found in chosen.items():
        if not found:
            raise ConfigError(
                f"{runs}: no run of arm {a!r} for seeds {' '.join(map(str, seeds))} "
                f"({run_path(runs, name, a, seeds[0])}, ...)"
            )
    curves = {a: [read_curve(run_path(runs, name, a, s), a, s) for s in chosen[a]] for a in algos}
    episodes = {c.episodes for cs in curves.values() for c in cs}
    if len(episodes) != 1:
        raise ConfigError(
            f"{runs}: the runs validate on different numbers of seeds {sorted(episodes)}"
        )
    (n_episodes,) = episodes
    baseline = baseline_level(scenario, n_episodes)
    summary = {a: aggregate(cs) for a, cs in curves.items()}
    level = baseline["capture_rate"]
    table = [
        "| algorithm | seeds reaching it | steps (median) | wall-clock (median) | per seed |",
        "|---|---|---|---|---|",
    ]
    times: dict[str, Any] = {}
    for algo, cs in curves.items():
        hits = {c.seed: time_to_baseline(c, level) for c in cs}
        reached = [h for h in hits.values() if h is not None]
        times[algo] = {
            str(s): (None if h is None else {"steps": h[0], "wall_s": h[1]})
            for s, h in hits.items()
        }
        per_seed = ", ".join(
            f"seed {s}: "
            + ("not reached" if h is None else f"{h[0]:,} steps / {_format_time(h[1])}")
            for s, h in hits.items()
        )
        if reached:
            steps = int(np.median([h[0] for h in reached]))
            walls = [h[1] for h in reached if not math.isnan(h[1])]
            wall = _format_time(float(np.median(walls)) if walls else math.nan)
            table.append(
                f"| {algo.upper()} | {len(reached)} of {len(cs)} | {steps:,} | {wall} "
                f"| {per_seed} |"
            )
        else:
            table.append(f"| {algo.upper()} | 0 of {len(cs)} | - | - | {per_seed} |")
    png = figure(curves, summary, baseline)
    rliable = seed_statistics.compute(final_scores(curves))
    profiles = rliable["performance_profiles"]
    images = {
        f"{REPORT}.png": png,
        **({f"{PROFILE}.png": profile_figure(profiles)} if profiles else {}),
    }
    host = machine()
    ratio = baseline["median_ratio_to_limit"]
    names = [sc.name for sc in mixture_scenarios(scenario)]
    where = f"`{scenario}`" if len(names) == 1 else f"each of {', '.join(names)} (pooled)"
    seed_text = ", ".join(map(str, seeds))
    if any(chosen[a] != list(seeds) for a in algos):
        seed_text = "; ".join(f"{a}: {', '.join(map(str, chosen[a]))}" for a in algos)
    lines = [
        f"# Learning curves on `{scenario}`",
        "",
        f"Validation on the first {n_episodes} validation seeds of {where} (never a published "
        "evaluation seed), deterministic actions, every `eval_freq` steps of each run; mean over "
        f"the training seeds {seed_text} with a 95% interval (Student's t over "
        "the seeds). The dashed line is `incremental_ik` on the same seeds: capture rate "
        f"{level:.2f}, median ratio to the physical limit {ratio:.2f}. Wall-clock is each run's "
        "training time, validations included.",
        "",
        f"![learning curves]({REPORT}.png)",
        "",
        f"## Time to `incremental_ik`'s validation capture rate ({level:.2f})",
        "",
        *table,
        "",
        *seed_statistics.markdown_lines(rliable),
        *([f"![performance profile]({PROFILE}.png)", ""] if profiles else []),
        "## Provenance",
        "",
        f"- command: `{command}`",
        f"- runs: `{runs}` ({', '.join(f'{a}: {len(cs)} seeds' for a, cs in curves.items())})",
        f"- machine: {host}",
        f"- git: `{git_state()}`",
        "",
    ]
    markdown = "\n".join(lines)
    out.mkdir(parents=True, exist_ok=True)
    stale = out / f"{PROFILE}.png"
    if not profiles and stale.is_file():
        stale.unlink()  # an earlier page's profile, of runs this page does not show
    for name, image in images.items():
        atomic_write(out / name, image)
    atomic_write(out / f"{REPORT}.md", markdown.encode())
    atomic_write(out / f"{REPORT}.html", _html(markdown, images).encode())
    numbers = {
        "scenario": scenario,
        "validation_episodes": n_episodes,
        "baseline": baseline,
        "curves": summary,
        "time_to_baseline": times,
        "rliable": rliable,
        "machine": host,
    }
    atomic_write(out / "curves.json", json.dumps(numbers, indent=2, default=_json).encode())
    return out / f"{REPORT}.md"


def _json(value: Any) -> Any:
    return float(value) if isinstance(value, np.floating) else int(value)


def _inline(text: str) -> str:
    """One line of the page's Markdown as HTML: escaped, each `` `code` `` span a ``<code>``."""
    import html
    import re

    return re.sub(r"`([^`]+)`", r"<code>\1</code>", html.escape(text))


def _html(markdown: str, images: dict[str, bytes]) -> str:
    """The page as one self-contained HTML file (the figures embedded, by file name): the
    Markdown's headings, paragraphs, lists, tables (each in a box that scrolls sideways on a
    narrow screen) and images, code spans as ``<code>``."""
    import html
    import re

    body = []
    block = ""  # the open table or list: "table", "ul" or ""
    for line in markdown.splitlines():
        kind = "table" if line.startswith("|") else "ul" if line.startswith("- ") else ""
        if block and kind != block:
            body.append("</table></div>" if block == "table" else "</ul>")
            block = ""
        if kind == "table":
            cells = [_inline(c.strip()) for c in line.strip("|").split("|")]
            if set("".join(cells)) <= set("-"):
                continue
            tag = "th" if not block else "td"
            opened = '<div class="scroll"><table>' if not block else ""
            body.append(opened + "<tr>" + "".join(f"<{tag}>{c}</{tag}>" for c in cells) + "</tr>")
            block = "table"
            continue
        if kind == "ul":
            body.append(("<ul>" if not block else "") + f"<li>{_inline(line[2:])}</li>")
            block = "ul"
            continue
        heading = re.match(r"(#{1,6}) (.*)", line)
        if line.startswith("!["):
            alt, name = line[2:-1].split("](")
            data = base64.b64encode(images[name]).decode()
            body.append(f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">')
        elif heading:
            level = len(heading.group(1))
            body.append(f"<h{level}>{_inline(heading.group(2))}</h{level}>")
        elif line:
            body.append(f"<p>{_inline(line)}</p>")
    if block:
        body.append("</table></div>" if block == "table" else "</ul>")
    style = (
        "body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;"
        "overflow-wrap:break-word}td,th{border:1px solid #ccc;padding:4px 8px}"
        "table{border-collapse:collapse}.scroll{overflow-x:auto}img{max-width:100%;height:auto}"
        "code{background:#f6f6f6;padding:0 0.2em}"
    )
    viewport = '<meta name="viewport" content="width=device-width, initial-scale=1">'
    head = f"<meta charset='utf-8'>{viewport}<title>learning curves</title><style>{style}</style>"
    return f"<!DOCTYPE html><html><head>{head}</head><body>{''.join(body)}</body></html>\n"


def train_runs(
    runs: Path, scenario: str, arms: list[str], seeds: list[int], extra: list[str]
) -> int:
    """Train (or resume) every run of each arm that has not finished; the first non-zero exit
    status."""
    from capture_bench.training.common.run import main as train_main

    for arm in arms:
        for seed in seeds:
            run_dir = run_path(runs, mixture_name(scenario), arm, seed)
            if is_finished(run_dir):
                print(f"{run_dir}: finished; kept")
                continue
            resume = (run_dir / "config.json").is_file()
            status = train_main(train_argv(run_dir, scenario, arm, seed, resume, extra))
            if status:
                return status
    return 0


def build_parser() -> argparse.ArgumentParser:
    from capture_bench.training.config.hyperparameters import ALGORITHMS

    parser = OneLineParser(
        prog="python -m capture_bench curves",
        description="Learning curves of train.py's algorithms on a scenario from several "
        "training seeds, against incremental_ik's level (markdown + HTML report).",
        epilog="example: python -m capture_bench curves --train --algos ppo sac --seeds 0 1 2",
    )
    parser.add_argument(
        "--algos",
        nargs="+",
        default=["ppo", "sac"],
        choices=ALGORITHMS,
        metavar="ALGO",
        help=f"algorithms (default: ppo sac; valid: {', '.join(ALGORITHMS)})",
    )
    parser.add_argument(
        "--seeds",
        nargs="+",
        type=int,
        default=[0, 1, 2],
        metavar="SEED",
        help="training seeds (default: 0 1 2)",
    )
    parser.add_argument(
        "--pixels",
        action="store_true",
        help="a second arm per algorithm, <algo>-pixels, trained on the camera's pixels "
        "(configs/pixels/<algo>.yaml: ppo has one)",
    )
    parser.add_argument(
        "--arms",
        nargs="+",
        metavar="ARM",
        help="instead of --algos: runs of these names, <runs>/<scenario>-<arm>-<seed>, each "
        "trained by its own command (e.g. ppo ppo-hold ppo-weighted), those of --seeds that exist; "
        "read only, not with --train",
    )
    parser.add_argument(
        "--scenario",
        default="paper",
        help="scenario, or a mixture (all, or a,b,c) whose runs validate on every scenario's "
        "seeds pooled (default: paper)",
    )
    parser.add_argument(
        "--runs", default="runs/curves", help="run directories (default: runs/curves)"
    )
    parser.add_argument("--out", default="reports/learning_curves", help="report folder")
    parser.add_argument(
        "--train", action="store_true", help="train or resume the unfinished runs first"
    )
    parser.add_argument(
        "--set",
        action="append",
        dest="overrides",
        metavar="KEY=VALUE",
        help="passed to train.py for new runs (e.g. --set total_timesteps=1000000)",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """``python -m capture_bench curves``; the exit status."""
    args_list = sys.argv[1:] if argv is None else argv
    try:
        args = build_parser().parse_args(args_list)
        from capture_bench.training.seeds import check_training_seed

        for scenario in mixture_scenarios(args.scenario):  # one, or a mixture's
            for seed in args.seeds:
                check_training_seed(seed, scenario)
        if args.arms and args.train:
            raise ConfigError(
                "--arms reads runs trained by their own commands; --train trains the --algos "
                "(with --pixels); train the arms with train.py --run-dir "
                f"{Path(args.runs) / mixture_name(args.scenario)}-<arm>-<seed>"
            )
        runs, out = Path(args.runs), Path(args.out)
        check_writable(out, "--out")
        if not rliable_stats.installed():
            raise ConfigError(rliable_stats.MISSING)
        arms = (
            list(dict.fromkeys(args.arms)) if args.arms else run_plan.arms(args.algos, args.pixels)
        )
        if args.train:
            check_writable(runs, "--runs")
            extra = [f"--set={item}" for item in args.overrides or []]
            status = train_runs(runs, args.scenario, arms, list(args.seeds), extra)
            if status:
                return status
        command = "python -m capture_bench curves " + " ".join(args_list)
        page = report(
            runs, out, args.scenario, arms, list(args.seeds), command, present_only=bool(args.arms)
        )
    except ConfigError as exc:
        print(f"curves: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except SystemExit as exc:
        return int(exc.code or 0)
    print(f"learning curves: {page} (and .html)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
