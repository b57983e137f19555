"""Local worker processes of a command (``evaluate.py --workers``, ``tune.py --workers``): how they
start (forked from a server that has imported what they need, else spawned; one numerical thread
each) and how each ends with the process that started it, however that one ends (``kill -9``
included).

A worker learns that its parent is gone from a pipe: the parent holds the only write end and
never writes, so the read end the worker waits on sees end-of-file when the parent ends, whoever
ends it (`end_with_parent`). Nothing else would end a worker: a pool worker waits for work
on a pipe it holds the write end of too, and the forkserver and multiprocessing's resource
tracker exit only once every worker has closed their pipes (each forked worker inherits both).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.connection import Connection
from typing import Any

#: One thread per worker for the numerical libraries: the workers are the parallelism. OpenBLAS
#: reads these when numpy is imported, so they must be in the environment the forkserver (or a
#: spawned worker) starts with, not set inside the worker. (Torch's threads are set where a model
#: is loaded or built.)
SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


@contextlib.contextmanager
def single_threaded_children() -> Iterator[None]:
    """Set `SINGLE_THREAD_ENV` (where the user has not) while worker processes start."""
    added = {k: v for k, v in SINGLE_THREAD_ENV.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)


def process_context(preload: Sequence[str] = ()) -> Any:
    """The start method's context: forkserver where there is one (the server imports
    ``preload`` once, so that each worker forks with those modules loaded), else spawn. The
    server starts with the first worker (or ``multiprocessing.forkserver.ensure_running()``), with
    the preload list set by then, and ends with this process."""
    method = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
    context = multiprocessing.get_context(method)
    if method == "forkserver" and preload:
        context.set_forkserver_preload(list(preload))
    return context


def end_with_parent(watched: Connection, when_gone: Callable[[], None]) -> None:
    """In a worker: call ``when_gone`` (in a daemon thread) once the parent process is gone.

    Args:
        watched: the read end of a pipe (``context.Pipe(duplex=False)``) whose write end only the
            parent holds and never writes to.
        when_gone: what the worker does then (e.g. ``os._exit``; it runs in the watching thread).
    """
    threading.Thread(
        target=_wait_for_parent, args=(watched, when_gone), name="end-with-parent", daemon=True
    ).start()


def _wait_for_parent(watched: Connection, when_gone: Callable[[], None]) -> None:
    with contextlib.suppress(EOFError, OSError):
        watched.recv_bytes()  # nothing is ever sent: this returns when the parent is gone
    when_gone()
