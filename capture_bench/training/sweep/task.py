"""One run of a sweep, as it runs on a Ray node: train.py in a temporary directory of that node,
and the run directory sent back whole as a tar archive.

Nothing here assumes the driver's filesystem: the task gets everything it reads as bytes (the
run directory to resume, the ``--config`` file) and returns everything it wrote, so the run can
happen on any node of the cluster and land under the driver's ``--runs``
(`capture_bench.training.sweep.command`). Ray's cancellation (``ray.cancel``, not forced) raises
KeyboardInterrupt in the task: train.py then saves a checkpoint, as on Ctrl-C, and the run
directory still comes back, resumable.
"""

from __future__ import annotations

import contextlib
import io
import os
import tarfile
import tempfile
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from capture_bench.training.common.run_plan import train_argv

#: Characters of a run's output kept in its result (the end: where an error is).
OUTPUT_TAIL = 4000


@dataclass(frozen=True)
class RunSpec:
    """One run to train: plain values, sent to the node.

    Attributes:
        name: the run directory's name, ``<scenario>-<arm>-<seed>``.
        scenario, arm, seed: what it trains (`capture_bench.training.common.run_plan`).
        options: train.py options of a new run (``--set``, ``--total-timesteps``), without
            ``--config`` and ``--device``.
        device: train.py's ``--device``, new or resumed.
        config: ``(file name, bytes)`` of the ``--config`` file, or None.
        partial: the tar archive of the run directory to resume, or None for a new run.
    """

    name: str
    scenario: str
    arm: str
    seed: int
    options: tuple[str, ...] = ()
    device: str = "cpu"
    config: tuple[str, bytes] | None = None
    partial: bytes | None = field(default=None, repr=False)


@dataclass(frozen=True)
class RunResult:
    """What a run sent back.

    Attributes:
        name: the run's name.
        status: train.py's exit status (1 where it raised; 130 where it was interrupted).
        error: one line saying what went wrong, or None.
        output: the end of train.py's output (stdout and stderr), `OUTPUT_TAIL` characters.
        node_id: the Ray node it ran on ("" outside Ray).
        node_ip: that node's IP address ("" outside Ray).
        archive: the run directory as the run left it (a tar archive), or None where it left
            nothing.
    """

    name: str
    status: int
    error: str | None
    output: str
    node_id: str
    node_ip: str
    archive: bytes | None = field(default=None, repr=False)


def pack(directory: Path) -> bytes:
    """``directory``'s files as an uncompressed tar archive, names relative to it."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for path in sorted(Path(directory).rglob("*")):
            tar.add(path, arcname=path.relative_to(directory).as_posix(), recursive=False)
    return buffer.getvalue()


def unpack(archive: bytes, directory: Path) -> None:
    """Extract a `pack` archive into ``directory`` (created); only plain files and folders
    inside it (tarfile's ``data`` filter)."""
    Path(directory).mkdir(parents=True, exist_ok=True)
    safe = {"filter": "data"} if hasattr(tarfile, "data_filter") else {}  # Python >= 3.10.12
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r") as tar:
        tar.extractall(directory, **safe)  # type: ignore[arg-type]


def _archive(run_dir: Path) -> bytes | None:
    return pack(run_dir) if run_dir.is_dir() and any(run_dir.iterdir()) else None


def _node() -> tuple[str, str]:
    """(Ray node ID, node IP) of this process, or ("", "") outside a Ray worker."""
    try:
        import ray
    except ImportError:
        return "", ""
    if not ray.is_initialized():
        return "", ""
    return ray.get_runtime_context().get_node_id(), ray.util.get_node_ip_address()


def _error_line(output: str) -> str:
    """train.py's error line (``train.py: error: ...``), else the output's last line."""
    lines = [line.strip() for line in output.splitlines() if line.strip()]
    errors = [line for line in lines if ": error: " in line]
    return (errors or lines or ["no output"])[-1]


def train_run(spec: RunSpec) -> RunResult:
    """Train (or resume) ``spec``'s run in a temporary directory and send it back."""
    node_id, node_ip = _node()
    output = io.StringIO()
    error: str | None = None
    archive: bytes | None = None
    with tempfile.TemporaryDirectory(prefix="capture-bench-sweep-") as tmp:
        run_dir = Path(tmp) / spec.name
        try:
            if spec.partial is not None:
                unpack(spec.partial, run_dir)
            options = list(spec.options)
            if spec.config is not None:
                name, data = spec.config
                config = Path(tmp) / "config" / os.path.basename(name)
                config.parent.mkdir()
                config.write_bytes(data)
                options += ["--config", str(config)]
            resume = spec.partial is not None
            argv = train_argv(run_dir, spec.scenario, spec.arm, spec.seed, resume, options)
            argv += ["--device", spec.device]
            from capture_bench.training.common.run import main as train_main

            with contextlib.redirect_stdout(output), contextlib.redirect_stderr(output):
                try:
                    status = train_main(argv)
                except Exception as exc:  # a failure inside training: its traceback and line
                    traceback.print_exc()
                    status = 1
                    error = " ".join(f"{type(exc).__name__}: {exc}".split())
        except KeyboardInterrupt:  # cancelled outside train.py's own handling
            status = 130
        if status and error is None:
            error = _error_line(output.getvalue())
        try:
            archive = _archive(run_dir)
        except KeyboardInterrupt:  # a cancel that came after training: send the run all the same
            archive = _archive(run_dir)
    return RunResult(
        spec.name, status, error, output.getvalue()[-OUTPUT_TAIL:], node_id, node_ip, archive
    )
