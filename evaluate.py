"""Evaluate agents on a leaderboard suite and write the report: capture-bench's main job.

    python evaluate.py                       # default suite: every scenario, 100 seeds, all agents
    python evaluate.py --suite quick         # smoke run
    python evaluate.py --agents incremental_ik models/dagger-dls-paper --scenarios paper
    python evaluate.py --help                # every option; python -m capture_bench list

The same command is installed as ``capture-bench-evaluate``. Everything it does is in
`capture_bench.evaluation.cli` (options, refusals, signals) and the modules it calls.
"""

from __future__ import annotations

from script_entry import command_main, run

__all__ = ["main"]

PROG = "evaluate.py"
COMMAND = "capture_bench.evaluation.cli:main"


def main(argv: list[str] | None = None) -> int:
    """Run the command (`capture_bench.evaluation.cli.main`); returns the exit status."""
    return command_main(COMMAND)(argv)


if __name__ == "__main__":
    raise SystemExit(run(PROG, COMMAND))
