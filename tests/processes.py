"""Child processes of the tests that stop a CLI with a signal: how to start one as a terminal
would, and what /proc says of it and of the workers it started (Linux)."""

from __future__ import annotations

import signal
import time
from pathlib import Path


def default_sigint() -> None:
    """``preexec_fn`` for a child that a test stops with Ctrl-C's signal: SIGINT at its default,
    as in a terminal. A process started in the background by a non-interactive shell (a CI
    runner, ``nohup ... &``) inherits SIGINT ignored, Python then installs no KeyboardInterrupt
    handler, and the child ran to the end (status 0, not 130)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _stat_fields(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name, or None if the process is gone."""
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` that /proc lists (zombies too): its children, theirs, and so on."""
    children = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = _stat_fields(int(entry.name))
            if fields is not None and int(fields[1]) == pid:
                children.append(int(entry.name))
    return children + [d for child in children for d in descendants(child)]


def alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    fields = _stat_fields(pid)
    return fields is not None and fields[0] != "Z"


def outliving(pids: list[int], seconds: float) -> list[int]:
    """Those of ``pids`` still alive after waiting up to ``seconds`` for them all to end."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and any(alive(pid) for pid in pids):
        time.sleep(0.1)
    return [pid for pid in pids if alive(pid)]
