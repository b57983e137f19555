"""Regenerate, or check, the generated tables of README.md and the documentation pages.

    python scripts/readme_table.py                  # rewrite the tables in README.md and docs/
    python scripts/readme_table.py --check          # exit 1 if any table differs from its source
    python scripts/readme_table.py --check README.md

A generated table sits between two markers, ``<!-- NAME:start -->`` and ``<!-- NAME:end -->``;
everything between them is replaced. The blocks and their sources:

* ``leaderboard``: the overall ranking of ``reports/published/default/results.json`` (the
  published leaderboard, which ``python evaluate.py --publish`` writes), the columns of the
  report's *Overall ranking* without its ``scenarios`` column, each cell formatted by the
  report's own `capture_bench.evaluation.report.ranking_cells`;
* ``leaderboard-scenarios``: the same report, one row per agent in ranking order, one column per
  scenario: capture rate · median ratio of capture time to the physical limit;
* ``scenarios``: the shipped scenarios (``configs/scenarios/*.yaml``): env ID and description;
* ``scenario-schema``: every key a scenario file may set, with its default, meaning and valid
  values, read from the dataclasses of `capture_bench.task.scenarios` and the validator's
  rules for them (`capture_bench.validation.Rule.describe`, the words of its error messages).

A file may hold any of the blocks; a file named on the command line must hold at least one.
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
from capture_bench.evaluation.aggregate import RankingRow
from capture_bench.evaluation.report import RANKING_HEADER, ranking_cells
from capture_bench.evaluation.reproduction import json_number
from capture_bench.task.scenarios import Scenario, list_scenarios, load_scenario
from capture_bench.task.scenarios import _schema as scenario_schema  # the validator's own rules

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "reports" / "published" / "default" / "results.json"
DEFAULT_FILES = ("README.md", "docs/scenarios.md", "docs/results/leaderboard.md")
DROPPED_COLUMN = "scenarios"  # the ranking's column README leaves out (every agent plays them all)


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _text(value: str) -> str:
    """Plain text for a table cell: ``<`` and ``>`` would start HTML tags in Markdown."""
    return value.replace("<", "&lt;").replace(">", "&gt;")


def _ranking(results: dict[str, Any]) -> list[RankingRow]:
    return [RankingRow.from_json(r) for r in results["ranking"]]


def leaderboard_table(results: dict[str, Any]) -> str:
    """The report's overall ranking, without its ``scenarios`` column."""
    keep = [i for i, name in enumerate(RANKING_HEADER) if name != DROPPED_COLUMN]
    rows = [ranking_cells(r) for r in _ranking(results)]
    return _md_table([RANKING_HEADER[i] for i in keep], [[row[i] for i in keep] for row in rows])


def _display_name(row: RankingRow) -> str:
    return row.agent + (" (privileged)" if row.privileged else "")


def scenario_results_table(results: dict[str, Any]) -> str:
    """Capture rate · median ratio to the physical limit, per agent (ranking order) and scenario."""
    cells = {(r["agent"], r["scenario"]): r for r in results["results"]}
    scenarios = sorted({r["scenario"] for r in results["results"]})
    rows = []
    for row in _ranking(results):
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
        rows.append(line)
    return _md_table(["agent", *scenarios], rows)


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


def _blocks(results_path: Path) -> dict[str, Callable[[], str]]:
    def results() -> dict[str, Any]:
        return json.loads(results_path.read_text())

    return {
        "leaderboard": lambda: leaderboard_table(results()),
        "leaderboard-scenarios": lambda: scenario_results_table(results()),
        "scenarios": scenarios_table,
        "scenario-schema": scenario_schema_table,
    }


def regenerate(text: str, blocks: dict[str, Callable[[], str]]) -> tuple[str, list[str]]:
    """``text`` with every marked block replaced by its table, and the names of the blocks."""
    found = []

    def fill(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in blocks:
            raise ValueError(f"unknown block {name!r}; known: {', '.join(sorted(blocks))}")
        found.append(name)
        return f"<!-- {name}:start -->\n{blocks[name]()}\n<!-- {name}:end -->"

    pattern = re.compile(r"<!-- ([\w-]+):start -->\n.*?<!-- \1:end -->", re.S)
    return pattern.sub(fill, text), found


def main(argv: Sequence[str] | None = None) -> int:
    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "files", nargs="*", help=f"markdown files (default: {', '.join(DEFAULT_FILES)})"
    )
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 on a difference"
    )
    parser.add_argument("--results", type=Path, default=RESULTS, help="the report's results.json")
    args = parser.parse_args(argv)
    blocks = _blocks(args.results)
    stale = []
    for name in args.files or DEFAULT_FILES:
        path = Path(name) if Path(name).is_absolute() or args.files else ROOT / name
        try:
            text = path.read_text()
            new, found = regenerate(text, blocks)
        except (OSError, ValueError) as err:
            print(f"readme_table.py: {path}: {err}", file=sys.stderr)
            return 2
        if not found:
            print(
                f"readme_table.py: {path}: no generated block (<!-- NAME:start -->)",
                file=sys.stderr,
            )
            return 2
        if new == text:
            continue
        if args.check:
            stale.append(f"{path} ({', '.join(found)})")
        else:
            path.write_text(new)
            print(f"rewrote {path}: {', '.join(found)}")
    if stale:
        print(
            "out of date: " + "; ".join(stale) + "; run python scripts/readme_table.py",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
