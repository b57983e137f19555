"""SIGTERM handled as Ctrl-C, so both CLIs end the same way on either signal; and both held back
where an interrupt must not land (`held_interrupts`).

A Python signal handler runs in the main thread wherever that thread is, which may be a weakref
callback or a ``__del__`` that the garbage collector calls; an exception raised there is printed
("Exception ignored in ...") and dropped, and the interrupt would be lost. While these handlers
are installed, such a dropped interrupt is delivered again by the same signal, a moment
later, so that it lands at the next point where it can propagate (`_redelivered`).
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

#: How long after an interrupt was dropped it is sent again.
REDELIVERY_DELAY_S = 0.05


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the main thread is, so that ``except KeyboardInterrupt`` handles it
    exactly as Ctrl-C (exit status 143 instead of 130)."""

    #: The signal (the root scripts read it: they catch interrupts before this module imports).
    signum = signal.SIGTERM


def exit_status(interrupt: KeyboardInterrupt) -> int:
    """The conventional status of a command ended by this signal: 128 + the signal's number."""
    return 128 + _signal_of(interrupt)


def _signal_of(interrupt: KeyboardInterrupt) -> int:
    """The signal whose handler raises this interrupt: SIGTERM for `Terminated`, else
    SIGINT."""
    return signal.SIGTERM if isinstance(interrupt, Terminated) else signal.SIGINT


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises `Terminated` in the main thread."""

    def handler(signum: int, frame: Any) -> None:
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        with _redelivered((signal.SIGTERM,)):
            yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class HeldInterrupts:
    """SIGINT and SIGTERM (those `held_interrupts` handles) raised only inside
    `raising` blocks; one that comes elsewhere is held (`pending`) and raised as the
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
    def holding(self) -> Iterator[None]:
        """Within the block the signals are held, even inside a `raising` block, which then
        raises one that came as this block ends: for bookkeeping inside the interruptible work
        (a trial's writes to its study's database while it trains)."""
        was_raising, self._raising = self._raising, False
        try:
            yield
        finally:
            self._raising = was_raising
        if was_raising and self.pending is not None:
            raise self.pending


@contextlib.contextmanager
def held_interrupts(signals: tuple[int, ...]) -> Iterator[HeldInterrupts]:
    """Within the block, ``signals`` (SIGINT, SIGTERM or both; main thread only) are handled by
    the `HeldInterrupts` it yields; the previous handlers are restored after it."""
    held = HeldInterrupts()
    previous = {signum: signal.signal(signum, held.handle) for signum in signals}
    try:
        with _redelivered(signals):
            yield held
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


@contextlib.contextmanager
def _redelivered(signals: tuple[int, ...]) -> Iterator[None]:
    """Within the block, an interrupt raised by the handler of one of ``signals`` where Python
    drops exceptions (``sys.unraisablehook``) is sent again to the main thread by that signal,
    `REDELIVERY_DELAY_S` later; other unraisable exceptions go to the previous hook. Sent
    from the hook itself, the signal's handler would run inside the hook, where the exception is
    dropped again: a timer thread sends it once the hook has long returned."""
    previous = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        exc = unraisable.exc_value
        signum = _signal_of(exc) if isinstance(exc, KeyboardInterrupt) else None
        if signum in signals:
            main = threading.main_thread().ident
            timer = threading.Timer(REDELIVERY_DELAY_S, signal.pthread_kill, (main, signum))
            timer.daemon = True
            timer.start()
        else:
            previous(unraisable)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Within the block (main thread), SIGINT and SIGTERM are held and one that came is raised
    as it ends: for short work that must not stop half-way (starting worker processes, renaming
    a folder into place). Held by their handlers, not by blocking them for this thread: in a
    process with other threads, another thread would receive the signal and its handler would
    still run here."""
    with held_interrupts((signal.SIGINT, signal.SIGTERM)) as held:
        yield
        with held.raising():
            pass


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
