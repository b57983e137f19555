"""What the root scripts (``evaluate.py``, ``train.py``, ``tune.py``) share: Ctrl-C and SIGTERM
end them from the first moment with one line on stderr and the exit status 130 or 143.

Only the standard library is imported here, so SIGTERM's handler is in place before the
command's modules import (seconds: torch, pybullet, gymnasium). An interrupt while they import
says "<script>: interrupted while starting; nothing written"; one the command does not handle
itself says "<script>: interrupted"; the command's own handler says what it wrote.
"""

from __future__ import annotations

import importlib
import signal
import sys


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised as Ctrl-C is, before the command's own handler is in place."""

    signum = signal.SIGTERM


def _terminated(signum: int, frame: object) -> None:
    raise _Terminated


def command_main(target: str):
    """The command's ``main`` (``"package.module:main"``), imported now."""
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def run(prog: str, target: str) -> int:
    """Run the command ``target`` (``"package.module:main"``) on ``sys.argv``; returns the exit
    status (see the module docstring for Ctrl-C and SIGTERM)."""
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _terminated)
    command = None
    try:
        command = command_main(target)
        return command(None)
    except KeyboardInterrupt as exc:  # one the command does not handle (before its handler)
        said = "interrupted while starting; nothing written" if command is None else "interrupted"
        print(f"{prog}: {said}", file=sys.stderr)
        return 128 + getattr(exc, "signum", signal.SIGINT)
