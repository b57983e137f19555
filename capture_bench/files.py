"""Checks and writes on the files a command produces: writable before work, whole when written."""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from capture_bench.validation import ConfigError


def check_writable(directory: str | Path, option: str) -> None:
    """Raise [`ConfigError`][capture_bench.ConfigError] unless files can be created in
    ``directory``.

    Nothing is left behind: a missing directory is not created; its nearest existing ancestor
    must be a directory where a probe file can be created (then removed). Run before the first
    episode or training step, so a bad output folder costs no work.

    Args:
        directory: where the command will write.
        option: the command-line option that named it, for the message (``--out``).
    """
    path = Path(directory)
    probe_in = path
    while not probe_in.exists():
        if probe_in.parent == probe_in:
            break
        probe_in = probe_in.parent
    if probe_in.exists() and not probe_in.is_dir():
        raise ConfigError(
            f"{option} {path}: {probe_in} is a file, not a folder; choose a writable folder"
        )
    try:
        handle, name = tempfile.mkstemp(prefix=".write-test-", dir=probe_in)
        os.close(handle)
        os.unlink(name)
    except OSError as exc:
        raise ConfigError(
            f"{option} {path}: cannot write in {probe_in} ({exc.strerror or exc}); "
            "choose a writable folder"
        ) from None


def atomic_write(path: Path, data: bytes | None = None, writer: Any = None) -> None:
    """Write ``data`` (or call ``writer(tmp_path)``) to a temporary file, then rename it onto
    ``path``: a reader never sees a half-written file."""
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    if writer is None:
        tmp.write_bytes(data or b"")
    else:
        writer(str(tmp))
    os.replace(tmp, path)


@contextlib.contextmanager
def directory_lock(directory: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``directory`` (``flock``, advisory) within the block: processes
    writing files there one after another take turns, each seeing what the one before wrote.
    Where the system gives no such lock (no ``fcntl``; a file system that refuses one on a
    folder, as NFS may), the block runs without it."""
    try:
        import fcntl
    except ImportError:  # not a POSIX system
        yield
        return
    try:
        handle = os.open(directory, os.O_RDONLY)
    except OSError:
        yield
        return
    try:
        with contextlib.suppress(OSError):
            fcntl.flock(handle, fcntl.LOCK_EX)
        yield
    finally:
        os.close(handle)  # releases the lock


def episode_file_name(agent: str, scenario: str, seed: int, suffix: str) -> str:
    """The file of one episode's figure or video: ``<agent>_<scenario>_seed<seed><suffix>``, every
    run of characters other than letters, digits, ``_``, ``.`` and ``-`` replaced by ``_``."""

    def safe(name: str) -> str:
        return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)

    return f"{safe(agent)}_{safe(scenario)}_seed{seed}{suffix}"
