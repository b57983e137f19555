"""Interrupts that land where Python drops exceptions (a finalizer the garbage collector runs) are
delivered again, so that a stop request is never lost."""

from __future__ import annotations

import signal
import sys
import time

import pytest

from capture_bench.interrupts import (
    Terminated,
    exit_status,
    held_interrupts,
    interrupts_deferred,
    sigterm_as_interrupt,
)


class SignalsInFinalizer:
    """An object whose finalizer receives ``signum``: its handler runs inside ``__del__``, where
    the exception it raises is dropped ("Exception ignored in ...")."""

    def __init__(self, signum: int) -> None:
        self.signum = signum

    def __del__(self) -> None:
        signal.raise_signal(self.signum)  # the handler runs before raise_signal returns


def drop_an_interrupt(signum: int) -> None:
    """Receive ``signum`` inside a finalizer, then wait for the interrupt to land here."""
    SignalsInFinalizer(signum)  # no reference kept: finalized at once
    time.sleep(30)  # a signal ends the sleep; without redelivery it ends after 30 s, no raise


def test_a_held_interrupt_dropped_in_a_finalizer_is_raised_again(capsys):
    for signum, kind in ((signal.SIGTERM, Terminated), (signal.SIGINT, KeyboardInterrupt)):
        with held_interrupts((signal.SIGINT, signal.SIGTERM)) as held:
            with pytest.raises(kind), held.raising():
                drop_an_interrupt(signum)
    assert "Exception ignored" not in capsys.readouterr().err


def test_sigterm_dropped_in_a_finalizer_is_raised_again(capsys):
    with sigterm_as_interrupt(), pytest.raises(Terminated):
        drop_an_interrupt(signal.SIGTERM)
    assert "Exception ignored" not in capsys.readouterr().err


def test_other_unraisable_exceptions_reach_the_previous_hook(monkeypatch):
    seen = []

    def previous_hook(unraisable):
        seen.append(unraisable)

    monkeypatch.setattr(sys, "unraisablehook", previous_hook)

    class Failing:
        def __del__(self) -> None:
            raise ValueError("in a finalizer")

    with held_interrupts((signal.SIGTERM,)):
        assert sys.unraisablehook is not previous_hook
        Failing()
    assert [type(u.exc_value) for u in seen] == [ValueError]
    assert sys.unraisablehook is previous_hook  # restored after the block


def test_exit_status_is_128_plus_the_signal():
    assert exit_status(Terminated()) == 128 + signal.SIGTERM == 143
    assert exit_status(KeyboardInterrupt()) == 128 + signal.SIGINT == 130


def test_a_deferred_interrupt_is_raised_as_the_block_ends():
    for signum, kind in ((signal.SIGTERM, Terminated), (signal.SIGINT, KeyboardInterrupt)):
        done = []
        with sigterm_as_interrupt():
            before = signal.getsignal(signum)
            with pytest.raises(kind), interrupts_deferred():
                signal.raise_signal(signum)
                signal.raise_signal(signum)  # a second one is not raised twice
                done.append(True)
            assert done == [True] and signal.getsignal(signum) == before
