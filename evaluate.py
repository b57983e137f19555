"""Evaluate agents on a leaderboard suite and write the report: capture-bench's main job.

    python evaluate.py                       # default suite: every scenario, 100 seeds, all agents
    python evaluate.py --suite quick         # smoke run
    python evaluate.py --agents incremental_ik models/ppo-paper --scenarios paper --episodes 20
    python evaluate.py --help                # every option; python -m capture_bench list

The same command is installed as ``capture-bench-evaluate``. Everything it does is in
:mod:`capture_bench.evaluation.cli` (options, refusals, signals) and the modules it calls.
"""

from __future__ import annotations

from capture_bench.evaluation.cli import main

__all__ = ["main"]

if __name__ == "__main__":
    raise SystemExit(main())
