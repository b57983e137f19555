"""Regenerate, or check, the generated blocks of README.md and the documentation pages.

    python scripts/readme_table.py                  # rewrite every block in README.md and docs/
    python scripts/readme_table.py --check          # exit 1 if any block differs from its source
    python scripts/readme_table.py --check README.md

A generated block sits between two markers, ``<!-- NAME ARGS:start -->`` and
``<!-- NAME ARGS:end -->`` (``ARGS``: none, or words separated by spaces); everything between them
is replaced. On lines of their own the markers hold a table (or a fenced block); on one line, as
``<!-- NAME ARGS:start -->value<!-- NAME ARGS:end -->``, they hold a value inside a sentence or a
table cell. The blocks and their sources:

* ``leaderboard``: the overall ranking of ``reports/published/default/results.json`` (the
  published leaderboard, which ``python evaluate.py --publish`` writes), the columns of the
  report's *Overall ranking* without its ``scenarios`` column, each cell formatted by the
  report's own `capture_bench.evaluation.reporting.report.ranking_cells`;
* ``leaderboard-scenarios``: the same report, one row per agent in ranking order, one column per
  scenario: capture rate · median ratio of capture time to the physical limit;
* ``published-cells AGENT...``: the same table for the named agents only (in the order named);
* ``published-models``: the same table for the reference agent and every trained model, by name;
* ``published-paired SCENARIO AGENT...``: on one scenario of the same report, for the named
  agents: captures, the median ratio to the physical limit, the paired difference of capture
  time against the report's reference agent and the probability of improvement over it (each
  with its 95% interval), and the median relative speed at capture;
* ``report KEY`` (a value): a count or figure of the same report, ``KEY`` one of `REPORT_KEYS`;
* ``report-summary``: those figures as a table (command, agents, scenarios, seeds, episodes,
  the run's wall-clock time and workers, its machine);
* ``reproduction-verdict``: what ``python evaluate.py`` prints at its end when it reproduces the
  published report episode for episode (the report compared with itself by
  `capture_bench.evaluation.reporting.reproduction`);
* ``test-reference-machine`` (a value): the machine and packages of
  ``tests/data/default_suite_reference.json``, which the test suite holds episodes to bit for bit;
* ``models``: every shipped model, ``models/*/metadata.json``'s model card: algorithm (a
  residual's base, an imitation's teacher), scenarios trained on, observation, training steps,
  the policy kept, and the card's validation under the current capture rule;
* ``model-commands``: every shipped model's training command, from its card;
* ``card MODEL KEY`` (a value): a figure of one model's card, ``KEY`` one of `CARD_KEYS`;
* ``scenarios``: the shipped scenarios (``configs/scenarios/*.yaml``): env ID and description;
* ``scenario-schema``: every key a scenario file may set, with its default, meaning and valid
  values, read from the dataclasses of `capture_bench.task.scenarios` and the validator's
  rules for them (`capture_bench.validation.Rule.describe`, the words of its error messages).

Without file arguments the files are README.md and every page under ``docs/`` holding a block. A
file named on the command line must hold at least one. ``--check`` names each block that differs.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from capture_bench.argparsing import OneLineParser
from capture_bench.evaluation.reporting.aggregate import RankingRow
from capture_bench.evaluation.reporting.report import RANKING_HEADER, ranking_cells
from capture_bench.evaluation.reporting.reproduction import (
    METRICS,
    compare,
    json_number,
    read_published,
    summary_lines,
)
from capture_bench.provenance import describe_machine
from capture_bench.task.scenarios import Scenario, list_scenarios, load_scenario
from capture_bench.task.scenarios import _schema as scenario_schema  # the validator's own rules

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "reports" / "published" / "default" / "results.json"
MODELS = ROOT / "models"
#: The machine whose episodes the test suite holds the evaluation to, bit for bit.
TEST_REFERENCE = ROOT / "tests" / "data" / "default_suite_reference.json"
DOCS = ROOT / "docs"
DROPPED_COLUMN = "scenarios"  # the ranking's column README leaves out (every agent plays them all)
#: The figures the ``report KEY`` value gives.
REPORT_KEYS = (
    "agents",
    "ranked-agents",
    "references",
    "scenarios",
    "ranked-scenarios",
    "not-ranked",
    "seeds",
    "episodes",
    "cells",
    "values",
    "reference",
    "wall-clock",
    "workers",
    "cpu",
)
MINUS = "\u2212"


def default_files() -> list[Path]:
    """README.md and every page under ``docs/`` that holds a generated block."""
    pages = [path for path in sorted(DOCS.rglob("*.md")) if BLOCK.search(path.read_text())]
    return [ROOT / "README.md", *pages]


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _text(value: str) -> str:
    """Plain text for a table cell: ``<`` and ``>`` would start HTML tags in Markdown."""
    return value.replace("<", "&lt;").replace(">", "&gt;")


def _signed(value: float, digits: int = 3) -> str:
    text = f"{value:.{digits}f}"
    if text.startswith("-") and float(text) == 0:  # a negative rounded to zero
        return text[1:]
    return MINUS + text[1:] if text.startswith("-") else text


def _ranking(results: dict[str, Any]) -> list[RankingRow]:
    return [RankingRow.from_json(r) for r in results["ranking"]]


def leaderboard_table(results: dict[str, Any]) -> str:
    """The report's overall ranking, without its ``scenarios`` column."""
    keep = [i for i, name in enumerate(RANKING_HEADER) if name != DROPPED_COLUMN]
    rows = [ranking_cells(r) for r in _ranking(results)]
    return _md_table([RANKING_HEADER[i] for i in keep], [[row[i] for i in keep] for row in rows])


def _display_name(row: RankingRow) -> str:
    return row.agent + (" (privileged)" if row.privileged else "")


def _agent_rows(results: dict[str, Any], names: Sequence[str]) -> list[RankingRow]:
    """The ranking rows of ``names`` in that order; a name matches an agent's label or the label
    without its parenthesised kind (``<name>`` for ``<name> (hybrid)`` or ``<name> (pixels)``)."""
    rows = _ranking(results)
    chosen = []
    for name in names:
        match = [r for r in rows if name in (r.agent, r.agent.split(" (")[0])]
        if not match:
            known = ", ".join(r.agent.split(" (")[0] for r in rows)
            raise ValueError(f"no agent {name!r} in {RESULTS.name}; known: {known}")
        chosen.append(match[0])
    return chosen


def _scenario_cells(results: dict[str, Any], rows: Sequence[RankingRow]) -> str:
    cells = {(r["agent"], r["scenario"]): r for r in results["results"]}
    scenarios = sorted({r["scenario"] for r in results["results"]})
    lines = []
    for row in rows:
        line = [_display_name(row)]
        for scenario in scenarios:
            cell = cells.get((row.agent, scenario))
            if cell is None:
                line.append("—")
                continue
            text = f"{round(100 * cell['capture_rate'])}%"
            ratio = json_number(cell["ratio_median"])
            if math.isfinite(ratio):
                text += f" · {ratio:.2f}×"
            line.append(text)
        lines.append(line)
    return _md_table(["agent", *scenarios], lines)


def scenario_results_table(results: dict[str, Any]) -> str:
    """Capture rate · median ratio to the physical limit, per agent (ranking order) and scenario."""
    return _scenario_cells(results, _ranking(results))


def published_cells_table(results: dict[str, Any], args: Sequence[str]) -> str:
    """`scenario_results_table` for the agents named in ``args``."""
    if not args:
        raise ValueError("published-cells needs the agents: <!-- published-cells A B:start -->")
    return _scenario_cells(results, _agent_rows(results, args))


def published_models_table(results: dict[str, Any]) -> str:
    """`scenario_results_table` for the reference and every trained model of the report."""
    models = {a["label"] for a in (results.get("provenance") or {}).get("agents", [])
              if a.get("kind") == "model"}  # fmt: skip
    rows = [r for r in _ranking(results) if r.agent == results["reference"] or r.agent in models]
    return _scenario_cells(
        results, sorted(rows, key=lambda r: (r.agent != results["reference"], r.agent))
    )


def _interval(cell: dict[str, Any], key: str, fmt: Callable[[float], str]) -> str:
    value = json_number(cell.get(key))
    if not math.isfinite(value):
        return "—"
    low, high = json_number(cell.get(f"{key}_low")), json_number(cell.get(f"{key}_high"))
    if math.isfinite(low) and math.isfinite(high):
        return f"{fmt(value)} [{fmt(low)}, {fmt(high)}]"
    return fmt(value)


def published_paired_table(results: dict[str, Any], args: Sequence[str]) -> str:
    """One scenario, the named agents: captures, median ratio, paired Δt and P(faster) against
    the reference, median relative speed at capture."""
    if len(args) < 2:
        raise ValueError(
            "published-paired needs a scenario and agents: "
            "<!-- published-paired paper A B:start -->"
        )
    scenario, names = args[0], args[1:]
    cells = {r["agent"]: r for r in results["results"] if r["scenario"] == scenario}
    if not cells:
        known = ", ".join(sorted({r["scenario"] for r in results["results"]}))
        raise ValueError(f"no scenario {scenario!r} in {RESULTS.name}; known: {known}")
    reference = results["reference"]
    header = [
        "agent",
        "captured",
        "median ratio to the limit [95%]",
        f"paired Δt against {reference}, s",
        f"P(better than {reference})",
        "rel. speed at capture, mm/s",
    ]
    rows = []
    for row in _agent_rows(results, names):
        cell = cells[row.agent]
        speed = json_number(cell.get("relative_speed_at_capture_median"))
        is_reference = row.agent == reference
        rows.append(
            [
                _display_name(row) + (" (reference)" if is_reference else ""),
                f"{cell['captured']}/{cell['episodes']}",
                _interval(cell, "ratio_median", lambda v: f"{v:.2f}"),
                "—" if is_reference else _interval(cell, "paired_time_difference", _signed),
                "—" if is_reference else _interval(cell, "prob_improvement", lambda v: f"{v:.2f}"),
                f"{1000 * speed:.0f}" if math.isfinite(speed) else "—",
            ]
        )
    return _md_table(header, rows)


def _scenario_names(results: dict[str, Any]) -> list[str]:
    return sorted({r["scenario"] for r in results["results"]})


def _not_ranked(results: dict[str, Any]) -> list[str]:
    unranked = set()
    for row in results["ranking"]:
        unranked.update(row.get("unranked") or [])
    return sorted(unranked)


def report_value(results: dict[str, Any], key: str) -> str:
    """One figure of the report (`REPORT_KEYS`), as a page quotes it."""
    provenance = results.get("provenance") or {}
    rows = _ranking(results)
    scenarios = _scenario_names(results)
    episodes = sorted({r["episodes"] for r in results["results"]})
    timing = provenance.get("timing") or {}
    values: dict[str, Callable[[], str]] = {
        "agents": lambda: str(len(rows)),
        "ranked-agents": lambda: str(sum(r.rank is not None for r in rows)),
        "references": lambda: ", ".join(r.agent for r in rows if r.privileged),
        "scenarios": lambda: str(len(scenarios)),
        "ranked-scenarios": lambda: str(len(scenarios) - len(_not_ranked(results))),
        "not-ranked": lambda: ", ".join(_not_ranked(results)),
        "seeds": lambda: "–".join(str(n) for n in episodes),
        "episodes": lambda: f"{sum(r['episodes'] for r in results['results']):,}",
        "cells": lambda: str(len(results["results"])),
        "values": lambda: str(len(METRICS) * len(results["results"])),
        "reference": lambda: str(results["reference"]),
        "wall-clock": lambda: f"{timing['wall_clock_s']:.0f} s",
        "workers": lambda: str((provenance.get("backend") or {})["workers"]),
        "cpu": lambda: describe_machine({"machine": provenance.get("machine") or {}}),
    }
    if key not in values:
        raise ValueError(f"report: unknown key {key!r}; known: {', '.join(REPORT_KEYS)}")
    try:
        return values[key]()
    except KeyError as err:
        raise ValueError(f"report {key}: {RESULTS.name} has no {err}") from None


def report_summary_table(results: dict[str, Any]) -> str:
    """The published report's counts and run, one figure a row."""
    provenance = results.get("provenance") or {}
    timing = provenance.get("timing") or {}
    backend = provenance.get("backend") or {}
    refs = report_value(results, "references")
    rows = [
        ["command", f"`{results.get('command') or provenance.get('command')}`"],
        ["suite", f"`{results['suite']}`"],
        [
            "agents",
            f"{report_value(results, 'agents')}: {report_value(results, 'ranked-agents')} ranked"
            + (f", {refs} a privileged reference" if refs else ""),
        ],
        [
            "scenarios",
            f"{report_value(results, 'scenarios')}: {report_value(results, 'ranked-scenarios')}"
            f" ranked, {report_value(results, 'not-ranked') or 'none'} not ranked",
        ],
        ["published seeds per scenario", report_value(results, "seeds")],
        ["episodes", report_value(results, "episodes")],
        ["reference of the paired comparisons", f"`{results['reference']}`"],
    ]
    if timing.get("wall_clock_s") is not None:
        rows.append(
            [
                "wall-clock of the run that wrote it",
                f"{timing['wall_clock_s']:.0f} s ({backend.get('name', '?')} backend, "
                f"{backend.get('workers', '?')} workers; GIFs and figures "
                f"{timing.get('media_wall_clock_s', float('nan')):.0f} s of it)",
            ]
        )
    rows.append(["its machine", describe_machine(provenance)])
    return _md_table(["the published report", "value"], rows)


def reproduction_verdict(results_path: Path) -> str:
    """The terminal lines of a run that reproduces the published report episode for episode."""
    report = read_published(results_path.parent)
    if report is None:
        raise ValueError(f"cannot read the report in {results_path.parent}")
    name = results_path.parent.relative_to(ROOT).as_posix() + "/"
    lines = summary_lines(compare(report, report, published_name=name))
    return "```text\n" + "\n".join(lines) + "\n```"


def _cards(models: Path) -> list[tuple[str, dict[str, Any], dict[str, Any]]]:
    """(name, metadata, model card) of every model directory with a card, by name."""
    found = []
    for meta_path in sorted(models.glob("*/metadata.json")):
        meta = json.loads(meta_path.read_text())
        if "model_card" in meta:
            found.append((meta_path.parent.name, meta, meta["model_card"]))
    if not found:
        raise ValueError(f"no model card (metadata.json with model_card) under {models}")
    return found


def _algorithm(meta: dict[str, Any], card: dict[str, Any]) -> str:
    text = str(meta["algorithm"])
    residual = meta.get("residual")
    if residual:
        text += f", residual on `{residual['base']}` (scale {residual['scale']})"
    imitation = card.get("imitation")
    if imitation:
        text += f", DAgger from `{imitation['teacher']}` ({imitation['rounds']} rounds)"
    return text


def _steps(meta: dict[str, Any], card: dict[str, Any]) -> str:
    imitation = card.get("imitation")
    steps = f"{card['total_timesteps']:,}"
    if imitation:
        return f"{imitation['environment_steps']:,} DAgger + {steps} {meta['algorithm']}"
    return steps


def _policy(card: dict[str, Any]) -> str:
    policy = card.get("policy") or {}
    if policy.get("kind") == "best validation":
        return f"best validation (step {policy['step']:,})"
    return str(policy.get("kind", "final"))


def _validation(card: dict[str, Any]) -> str:
    parts = []
    for scenario, v in card["validation"].items():
        text = f"{scenario} {sum(bool(e['captured']) for e in v['episodes'])}/{len(v['seeds'])}"
        ratio = json_number(v.get("median_ratio_to_limit"))
        if math.isfinite(ratio):
            text += f" · {ratio:.2f}×"
        parts.append(text)
    return "; ".join(parts)


def models_table(models: Path) -> str:
    """Every shipped model's card: what it is and its validation under the current rule."""
    rows = []
    for name, meta, card in _cards(models):
        scenarios = card.get("scenarios") or [meta.get("scenario")]
        source = meta.get("observation_source") or "ekf"
        rows.append(
            [
                f"`{name}`",
                _algorithm(meta, card),
                ", ".join(scenarios) if len(scenarios) < 3 else f"all {len(scenarios)}",
                "pixels" if source == "pixels" else f"the estimate (`{source}`)",
                _steps(meta, card),
                _policy(card),
                "v0 (eq. 20 alone)" if "validation_v0" in card else "the envelope",
                _validation(card),
            ]
        )
    header = [
        "model",
        "algorithm",
        "trained on",
        "observation",
        "training steps",
        "policy shipped",
        "trained under",
        "validation under the envelope: captured · median ratio",
    ]
    return _md_table(header, rows)


#: The figures the ``card MODEL KEY`` value gives.
CARD_KEYS = ("steps", "wall-clock", "steps-per-second", "cpu", "cores")


def card_value(models: Path, name: str, key: str) -> str:
    """One figure of a shipped model's card (`CARD_KEYS`)."""
    cards = {n: (meta, card) for n, meta, card in _cards(models)}
    if name not in cards:
        raise ValueError(f"card: no model {name!r} under {models}; known: {', '.join(cards)}")
    meta, card = cards[name]
    hardware = card.get("hardware") or {}
    values: dict[str, Callable[[], str]] = {
        "steps": lambda: f"{card['total_timesteps']:,}",
        "wall-clock": lambda: f"{card['wall_time_s']:,.0f} s",
        "steps-per-second": lambda: f"{card['total_timesteps'] / card['wall_time_s']:,.0f}",
        "cpu": lambda: describe_machine({"machine": hardware}),
        "cores": lambda: str(hardware["cores"]),
    }
    if key not in values:
        raise ValueError(f"card: unknown key {key!r}; known: {', '.join(CARD_KEYS)}")
    return values[key]()


def model_commands_table(models: Path) -> str:
    """Every shipped model's training command and training seed, from its card."""
    rows = [[f"`{name}`", f"`{card['command']}`"] for name, _, card in _cards(models)]
    return _md_table(["model", "command (its card)"], rows)


def scenarios_table() -> str:
    """The shipped scenarios: registered env ID and the file's description."""
    rows = []
    for name in list_scenarios():
        scenario = load_scenario(name)
        rows.append([f"`{scenario.env_id}`", f"`{name}`", _text(scenario.description)])
    return _md_table(["ID", "file", "what"], rows)


def _default_text(f: dataclasses.Field) -> str:
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return "—"
    return f"`{json.dumps(list(value) if isinstance(value, tuple) else value)}`"


def _schema_rows(cls: type, schema: dict[str, Any], prefix: str) -> list[list[str]]:
    rows = []
    for f in dataclasses.fields(cls):
        rule = schema[f.name]
        if isinstance(rule, dict):  # a section: its keys, dotted
            rows += _schema_rows(f.default_factory, rule, f"{prefix}{f.name}.")
            continue
        doc = _text(f.metadata.get("doc", ""))
        rows.append([f"`{prefix}{f.name}`", _default_text(f), doc, rule.describe()])
    return rows


def scenario_schema_table() -> str:
    """Every key of a scenario file (dotted for sections), its default, meaning and valid values."""
    rows = _schema_rows(Scenario, scenario_schema(Scenario), "")
    return _md_table(["key", "default", "what, unit", "valid"], rows)


def _card_block(models: Path, args: Sequence[str]) -> str:
    if len(args) != 2:
        raise ValueError(f"block 'card' takes a model and a key ({', '.join(CARD_KEYS)})")
    return card_value(models, *args)


#: A block's text from its arguments.
Block = Callable[[Sequence[str]], str]


def _no_args(name: str, make: Callable[[], str]) -> Block:
    def block(args: Sequence[str]) -> str:
        if args:
            raise ValueError(f"block {name!r} takes no arguments, got {' '.join(args)!r}")
        return make()

    return block


def _one_arg(name: str, make: Callable[[str], str]) -> Block:
    def block(args: Sequence[str]) -> str:
        if len(args) != 1:
            raise ValueError(f"block {name!r} takes one argument ({', '.join(REPORT_KEYS)})")
        return make(args[0])

    return block


def _blocks(results_path: Path, models: Path = MODELS) -> dict[str, Block]:
    cache: dict[str, Any] = {}

    def results() -> dict[str, Any]:
        if "results" not in cache:
            cache["results"] = json.loads(results_path.read_text())
        return cache["results"]

    blocks: dict[str, Block] = {
        "leaderboard": _no_args("leaderboard", lambda: leaderboard_table(results())),
        "leaderboard-scenarios": _no_args(
            "leaderboard-scenarios", lambda: scenario_results_table(results())
        ),
        "published-cells": lambda args: published_cells_table(results(), args),
        "published-models": _no_args("published-models", lambda: published_models_table(results())),
        "published-paired": lambda args: published_paired_table(results(), args),
        "report": _one_arg("report", lambda key: report_value(results(), key)),
        "report-summary": _no_args("report-summary", lambda: report_summary_table(results())),
        "reproduction-verdict": _no_args(
            "reproduction-verdict", lambda: reproduction_verdict(results_path)
        ),
        "test-reference-machine": _no_args(
            "test-reference-machine",
            lambda: describe_machine(json.loads(TEST_REFERENCE.read_text())),
        ),
        "models": _no_args("models", lambda: models_table(models)),
        "model-commands": _no_args("model-commands", lambda: model_commands_table(models)),
        "card": lambda args: _card_block(models, args),
        "scenarios": _no_args("scenarios", scenarios_table),
        "scenario-schema": _no_args("scenario-schema", scenario_schema_table),
    }
    return {name: _remembered(block) for name, block in blocks.items()}


def _remembered(block: Block) -> Block:
    """``block``, each text made once per arguments (the sources do not change during a run)."""
    made: dict[tuple[str, ...], str] = {}

    def remembered(args: Sequence[str]) -> str:
        key = tuple(args)
        if key not in made:
            made[key] = block(key)
        return made[key]

    return remembered


#: A block: its markers on lines of their own around a table, or on one line around a value
#: (a marker quoted in a code span, after a backtick, is text).
BLOCK = re.compile(
    r"(?<!`)<!-- (?P<tag>(?P<name>[\w-]+)(?P<args>(?: [^\s:>]+)*)):start -->"
    r"(?P<newline>\n?)(?P<body>.*?)<!-- (?P=tag):end -->",
    re.S,
)


def regenerate(text: str, blocks: dict[str, Block]) -> tuple[str, list[str], list[str]]:
    """``text`` with every marked block replaced by its source's text, the blocks found (each as
    ``NAME ARGS``) and those whose text differed."""
    found: list[str] = []
    stale: list[str] = []

    def fill(match: re.Match[str]) -> str:
        tag, name = match.group("tag"), match.group("name")
        if name not in blocks:
            raise ValueError(f"unknown block {name!r}; known: {', '.join(sorted(blocks))}")
        content = blocks[name](match.group("args").split())
        found.append(tag)
        if match.group("newline"):
            new = f"<!-- {tag}:start -->\n{content}\n<!-- {tag}:end -->"
        else:
            if "\n" in content or "\n" in match.group("body"):
                raise ValueError(
                    f"block {tag!r} on one line holds a value, not a table: "
                    "put its markers on lines of their own"
                )
            if match.start() == 0 or text[match.start() - 1] == "\n":
                raise ValueError(
                    f"value {tag!r} starts a line, where Markdown reads the comment as a block "
                    "and breaks the paragraph: put a word before it"
                )
            new = f"<!-- {tag}:start -->{content}<!-- {tag}:end -->"
        if new != match.group(0):
            stale.append(tag)
        return new

    return BLOCK.sub(fill, text), found, stale


def main(argv: Sequence[str] | None = None) -> int:
    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "files",
        nargs="*",
        help="markdown files (default: README.md and every docs page with a block)",
    )
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 on a difference"
    )
    parser.add_argument("--results", type=Path, default=RESULTS, help="the report's results.json")
    parser.add_argument("--models", type=Path, default=MODELS, help="the shipped models' folder")
    args = parser.parse_args(argv)
    blocks = _blocks(args.results, args.models)
    stale = []
    for path in [Path(name) for name in args.files] or default_files():
        try:
            text = path.read_text()
            new, found, changed = regenerate(text, blocks)
        except (OSError, ValueError) as err:
            print(f"readme_table.py: {path}: {err}", file=sys.stderr)
            return 2
        if not found:
            print(
                f"readme_table.py: {path}: no generated block (<!-- NAME:start -->)",
                file=sys.stderr,
            )
            return 2
        if not changed:
            continue
        if args.check:
            stale.append(f"{path} ({', '.join(changed)})")
        else:
            path.write_text(new)
            print(f"rewrote {path}: {', '.join(changed)}")
    if stale:
        print(
            "out of date: " + "; ".join(stale) + "; run python scripts/readme_table.py",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
