"""The stored reference of the default suite's episodes that ``tests/test_batched_evaluation.py``
holds the evaluation to, bit for bit, on the kind of machine that made it.

    python scripts/suite_reference.py            # add the rows of agents the reference lacks
    python scripts/suite_reference.py --check    # list them; exit 1 if any
    python scripts/suite_reference.py --rebuild  # every row anew (after a change of the rules)

The reference (``tests/data/default_suite_reference.csv``) holds every default-suite agent's
episodes on the first two published seeds of every scenario, as ``episodes.csv`` writes them,
timing columns removed, each episode played in its own single ``CaptureEnv``; an agent added to
the suite gets its rows from that same path (`run_task`,
one episode per env) at a clean commit, and the ``.json`` beside the file names the commit that
made each agent's rows.
``--rebuild`` replaces every row the same way, for a change of the task's rules that changes
every score (a new environment version); the ``.json`` then names that commit alone.
Rows are added only on a machine whose `fingerprint` is the reference's: floats agree bit
for bit only there (docs/evaluation.md, Reproducibility). Rows already there are never rewritten.
"""

from __future__ import annotations

import csv
import io
import json
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

REFERENCE = (
    Path(__file__).resolve().parent.parent / "tests" / "data" / "default_suite_reference.csv"
)
EPISODES_PER_SCENARIO = 2


def fingerprint(machine: Mapping[str, Any], packages: Mapping[str, Any]) -> dict[str, Any]:
    """What decides the last bits of a float here
    (`capture_bench.provenance.reproduction_key`)."""
    from capture_bench.provenance import reproduction_key

    return reproduction_key(machine, packages)


def this_machine() -> dict[str, Any]:
    from capture_bench.provenance import reproduction_key

    return reproduction_key()


def stored() -> tuple[dict[str, Any], dict[tuple[str, str, str], dict[str, str]]]:
    """The reference's provenance (the ``.json``) and its rows keyed by (agent, scenario, seed)."""
    made = json.loads(REFERENCE.with_suffix(".json").read_text())
    with REFERENCE.open(newline="") as handle:
        rows = {(r["agent"], r["scenario"], r["seed"]): r for r in csv.DictReader(handle)}
    return made, rows


def suite_tasks():
    """The default suite's tasks on the reference's seeds, in the evaluation's order."""
    from capture_bench.evaluation.pipeline import EvaluationConfig, plan_evaluation

    config = EvaluationConfig(suite="default", episodes=EPISODES_PER_SCENARIO, workers=1)
    return plan_evaluation(config).tasks


def task_key(task) -> tuple[str, str, str]:
    """A task's (agent, scenario, seed) as its record, and so the reference's row, names them."""
    from capture_bench.evaluation.running.backends import scenario_label, task_spec

    return task_spec(task).label, scenario_label(task.scenario), str(task.seed)


def missing_agents(tasks, rows: Mapping[tuple[str, str, str], Any]) -> list[str]:
    """The labels of the suite's agents with an episode the reference has no row for, in the
    suite's order."""
    keys = [task_key(task) for task in tasks]
    return list(dict.fromkeys(key[0] for key in keys if key not in rows))


def main(argv: list[str] | None = None) -> int:
    from capture_bench.argparsing import OneLineParser

    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="list missing agents; exit 1 if any")
    parser.add_argument(
        "--rebuild", action="store_true", help="replace every row (a change of the task's rules)"
    )
    args = parser.parse_args(argv)

    made, rows = stored()
    tasks = suite_tasks()
    if args.rebuild:
        rows = {}
    missing = missing_agents(tasks, rows)
    if args.check or not missing:
        print("agents without reference rows: " + (", ".join(missing) or "none"))
        return 1 if missing else 0

    from capture_bench.evaluation.reporting.merge import episode_cells
    from capture_bench.evaluation.running.backends import run_task
    from capture_bench.files import atomic_write
    from capture_bench.provenance import git_state

    there, here = fingerprint(made["machine"], made["packages"]), this_machine()
    if here != there:
        parser.error(
            f"rows are added only on the reference's kind of machine ({there}); this one is {here}"
        )
    git = git_state()
    if git.get("dirty"):
        parser.error(
            "the working tree has uncommitted changes: add rows at a clean commit, so "
            "the .json can name the code that made them"
        )
    added = [task for task in tasks if task_key(task)[0] in missing]
    rows = [episode_cells(run_task(task)[0]) for task in added]  # all played before a write
    old = REFERENCE.read_bytes()
    newline = "\r\n" if old.split(b"\n", 1)[0].endswith(b"\r") else "\n"  # the file's own
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]), lineterminator=newline)
    if args.rebuild:
        from capture_bench.provenance import machine, package_versions

        writer.writeheader()
        old = b""
        made = {
            "made_by": "scripts/suite_reference.py --rebuild: each episode in its own single "
            "CaptureEnv (run_task)",
            "git": git,
            "machine": machine(),
            "packages": package_versions(),
        }
    writer.writerows(rows)
    made.setdefault("added", []).append(
        {
            "agents": missing,
            "made_by": "scripts/suite_reference.py: each episode in its own single CaptureEnv "
            "(run_task)",
            "git": git,
        }
    )
    atomic_write(REFERENCE, old + buffer.getvalue().encode())
    atomic_write(REFERENCE.with_suffix(".json"), (json.dumps(made, indent=2) + "\n").encode())
    print(f"added {len(added)} rows: {', '.join(missing)} at {git['commit'][:7]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
