"""Tune an algorithm's hyper-parameters on a capture-bench scenario with Optuna.

    python tune.py --algo sac --scenario paper --trials 50 --n-timesteps 100000
    python tune.py --algo sac --scenario paper --trials 50        # 50 more, same study
    python tune.py --algo sac --scenario paper --trials 40 --workers 4   # 4 trials at a time
    python train.py --algo sac --config runs/tune-paper-sac/best.yaml

The same command is installed as ``capture-bench-tune`` (needs the ``tune`` extra:
``pip install 'capture-bench[tune]'``). Everything it does is in
:mod:`capture_bench.training.tune`.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable

__all__ = ["main"]

PROG = "tune.py"


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised as Ctrl-C is, before the command's own handler is in place."""

    signum = signal.SIGTERM


def _terminated(signum: int, frame: object) -> None:
    raise _Terminated


def _command() -> Callable[[list[str] | None], int]:
    from capture_bench.training.tune import main as command  # the heavy imports

    return command


def main(argv: list[str] | None = None) -> int:
    """Run the command (:func:`capture_bench.training.tune.main`); returns the exit status."""
    return _command()(argv)


def _run() -> int:
    """:func:`main`, Ctrl-C and SIGTERM ending it from the first moment with one line on stderr
    and the exit status 130 or 143: the command's own line once it runs; while its modules
    import (seconds), "tune.py: interrupted while starting; nothing written". Only the standard
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
