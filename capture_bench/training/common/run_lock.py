"""One train.py per run directory: an exclusive lock on the directory for the run's whole life.

A new run and a resume both take it (``flock`` on the directory itself, so taking it writes
nothing) before they write anything there; a second train.py on the same directory is refused
in one line naming the process that holds it. The operating system releases the lock when its
holder ends, however it ends (a crash, ``kill -9``), so no stale lock is ever left behind. The
holder's process id comes from ``/proc/locks`` (Linux); elsewhere the message names none. Where
the file system cannot lock (some network file systems, or no ``fcntl``: Windows), the run goes
on unlocked.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
from types import TracebackType

from capture_bench.validation import ConfigError

try:
    import fcntl
except ImportError:  # Windows: no flock
    fcntl = None  # type: ignore[assignment]


class RunLock:
    """The lock this process holds on a run directory, if any (a context manager that releases
    it on exit). `acquire` takes it. For a new run, the caller records what the directory
    held when locked (`found`) and whether it created it (`created`), so that
    `discard` can leave the directory as it was; both stay unset for a resume."""

    def __init__(self) -> None:
        self.fd: int | None = None
        self.run_dir: Path | None = None
        self.found: frozenset[str] | None = None
        self.created = False

    def acquire(self, run_dir: Path) -> None:
        """Lock ``run_dir`` (an existing directory) for this process.

        Raises:
            ConfigError: another process holds it; the message names the directory and, where
                the system says, the holder's process id.
        """
        if self.run_dir is not None and Path(run_dir) == self.run_dir:
            return
        if fcntl is None:
            return
        try:
            fd = os.open(run_dir, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        except OSError:  # unreadable: the checks that follow say why
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _holder(fd)
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return  # the file system cannot lock: go on unlocked
            pid = f" (pid {holder})" if holder else ""
            raise ConfigError(
                f"{run_dir}: in use by another train.py{pid}; wait for it to end, or stop it "
                f"(Ctrl-C saves a checkpoint) and continue with: python train.py --resume "
                f"{run_dir}"
            ) from None
        self.fd, self.run_dir = fd, Path(run_dir)

    def release(self) -> None:
        """Release the lock (nothing where none is held)."""
        if self.fd is not None:
            os.close(self.fd)  # closing the last descriptor releases the flock
        self.fd, self.run_dir = None, None

    def discard(self, run_dir: Path) -> None:
        """Remove what this process wrote into ``run_dir`` (a new run that failed before its
        first checkpoint): every entry the directory did not hold when locked (`found`),
        and the directory itself where this process created it. Nothing for a resume."""
        import shutil

        if self.found is None or not run_dir.is_dir():
            return
        for entry in run_dir.iterdir():
            if entry.name in self.found:
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                entry.unlink(missing_ok=True)
        if self.created:
            try:
                run_dir.rmdir()
            except OSError:  # not empty: leave it
                pass

    def __enter__(self) -> RunLock:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.release()


def _holder(fd: int) -> int | None:
    """The process id holding a flock on the file of ``fd``, from ``/proc/locks``, or None."""
    stat = os.fstat(fd)
    device = f"{os.major(stat.st_dev):02x}:{os.minor(stat.st_dev):02x}:{stat.st_ino}"
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        fields = line.split()
        # "1: FLOCK  ADVISORY  WRITE 5379 fe:00:2149162 0 EOF" (blocked waiters start "->")
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[5] == device:
            pid = int(fields[4]) if fields[4].isdigit() else 0
            return pid if pid > 0 else None
    return None
