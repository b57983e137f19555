"""Silence what C extensions write straight to the process's stdout/stderr file descriptors.

pybullet prints its build time when imported and ``argv[0]=`` on every connection, from C, so
``contextlib.redirect_stdout`` cannot catch it; ``evaluate.py`` opens one connection per scenario
per worker, and those lines would break up its progress display.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def quiet_c_output() -> Iterator[None]:
    """Point file descriptors 1 and 2 at /dev/null inside the block (Python output is flushed
    first, so nothing of ours is lost); a no-op where they cannot be duplicated."""
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = (os.dup(1), os.dup(2))
    except (OSError, ValueError, AttributeError):
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)
