"""Evaluate agents on a leaderboard suite and write the report: capture-bench's main job.

    python evaluate.py                       # default suite: every scenario, 100 seeds, all agents
    python evaluate.py --suite quick         # smoke run
    python evaluate.py --agents incremental_ik models/ppo-paper --scenarios paper --episodes 20
    python evaluate.py --help                # every option; python -m capture_bench list

The same command is installed as ``capture-bench-evaluate``. Everything it does is in
:mod:`capture_bench.evaluation.cli` (options, refusals, signals) and the modules it calls.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable

__all__ = ["main"]

PROG = "evaluate.py"


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised as Ctrl-C is, before the command's own handler is in place."""

    signum = signal.SIGTERM


def _terminated(signum: int, frame: object) -> None:
    raise _Terminated


def _command() -> Callable[[list[str] | None], int]:
    from capture_bench.evaluation.cli import main as command  # the heavy imports

    return command


def main(argv: list[str] | None = None) -> int:
    """Run the command (:func:`capture_bench.evaluation.cli.main`); returns the exit status."""
    return _command()(argv)


def _run() -> int:
    """:func:`main`, Ctrl-C and SIGTERM ending it from the first moment with one line on stderr
    and the exit status 130 or 143: the command's own line once it runs; while its modules
    import (seconds), "evaluate.py: interrupted while starting; nothing written". Only the standard
    library is imported before SIGTERM's handler is installed here."""
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _terminated)
    command = None
    try:
        command = _command()
        return command(None)
    except KeyboardInterrupt as exc:  # one the command does not handle (before its handler)
        said = "interrupted while starting; nothing written" if command is None else "interrupted"
        print(f"{PROG}: {said}", file=sys.stderr)
        return 128 + getattr(exc, "signum", signal.SIGINT)


if __name__ == "__main__":
    raise SystemExit(_run())
