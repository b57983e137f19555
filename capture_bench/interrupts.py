"""SIGTERM handled as Ctrl-C, so both CLIs end the same way on either signal."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from typing import Any


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the main thread is, so that ``except KeyboardInterrupt`` handles it
    exactly as Ctrl-C (exit status 143 instead of 130)."""


def exit_status(interrupt: KeyboardInterrupt) -> int:
    """The conventional status of a command ended by this signal: 128 + the signal's number."""
    return 128 + (signal.SIGTERM if isinstance(interrupt, Terminated) else signal.SIGINT)


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` in the main thread."""

    def handler(signum: int, frame: Any) -> None:
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
