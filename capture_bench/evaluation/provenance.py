"""Provenance of a report: code version, configuration hashes, package versions."""

from __future__ import annotations

import hashlib
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

from capture_bench.paths import CHECKOUT_DIR

REPO_ROOT = CHECKOUT_DIR  # git describes the checkout (no commit in a wheel install)
PACKAGES = (
    "capture-bench",
    "numpy",
    "scipy",
    "gymnasium",
    "pybullet",
    "filterpy",
    "stable-baselines3",
    "torch",
    "matplotlib",
    "ray",
)


def git_state(root: Path = REPO_ROOT) -> dict[str, object]:
    """``{"commit": sha or None, "dirty": bool or None}`` of the repository at ``root``."""

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(
                ["git", *args], cwd=root, capture_output=True, text=True, timeout=10, check=True
            )
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip()

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "dirty": None if status is None else bool(status)}


def package_versions(names: tuple[str, ...] = PACKAGES) -> dict[str, str | None]:
    """Installed version of each package (None if absent), plus Python's."""
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def display_path(path: Path) -> str:
    """``path`` relative to the checkout where it lies inside it (``configs/suites/default.yaml``,
    ``models/ppo-paper``), so that a committed report names no machine's folders; else absolute."""
    resolved = Path(path).resolve()
    try:
        return resolved.relative_to(CHECKOUT_DIR).as_posix()
    except ValueError:
        return str(resolved)


def machine() -> dict[str, object]:
    """The machine a report was computed on: batched and single linear algebra round differently
    on different CPUs' BLAS kernels, so results are reproducible to rounding across machines."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "system": platform.system()}


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
