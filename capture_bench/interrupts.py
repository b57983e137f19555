"""SIGTERM handled as Ctrl-C, so both CLIs end the same way on either signal; and both held back
where an interrupt must not land (:func:`held_interrupts`)."""

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


class HeldInterrupts:
    """SIGINT and SIGTERM (those :func:`held_interrupts` handles) raised only inside
    :meth:`raising` blocks; one that comes elsewhere is held (:attr:`pending`) and raised as the
    next such block starts. So an interrupt lands only where the code is ready for it (a trial's
    training), never halfway through bookkeeping that must finish (a database write)."""

    def __init__(self) -> None:
        self.pending: KeyboardInterrupt | None = None
        self._raising = False

    def handle(self, signum: int, frame: Any) -> None:
        interrupt = Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
        if self._raising:
            raise interrupt
        if self.pending is None:
            self.pending = interrupt

    @contextlib.contextmanager
    def raising(self) -> Iterator[None]:
        """Within the block the signals raise at once, a held one as the block starts."""
        self._raising = True
        try:
            if self.pending is not None:
                raise self.pending
            yield
        finally:
            self._raising = False


@contextlib.contextmanager
def held_interrupts(signals: tuple[int, ...]) -> Iterator[HeldInterrupts]:
    """Within the block, ``signals`` (SIGINT, SIGTERM or both; main thread only) are handled by
    the :class:`HeldInterrupts` it yields; the previous handlers are restored after it."""
    held = HeldInterrupts()
    previous = {signum: signal.signal(signum, held.handle) for signum in signals}
    try:
        yield held
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM wait (blocked for this thread) and arrive when it
    ends: for work that must not stop half-way, such as renaming a folder into place (Unix)."""
    held = {signal.SIGINT, signal.SIGTERM}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


@contextlib.contextmanager
def signals_ignored() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM are ignored (and one that comes is lost): for the
    short work that ends a command already stopping, which a second Ctrl-C would leave half
    done."""
    previous = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
