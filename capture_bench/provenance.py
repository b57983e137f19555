"""Provenance of a report, a training run or a shipped model: code version, file hashes, package
versions, the machine."""

from __future__ import annotations

import hashlib
import os
import platform
import subprocess
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

from capture_bench.paths import CHECKOUT_DIR

REPO_ROOT = CHECKOUT_DIR  # git describes the checkout (no commit in a wheel install)
PACKAGES = (
    "capture-bench",
    "numpy",
    "scipy",
    "gymnasium",
    "pybullet",
    "stable-baselines3",
    "torch",
    "matplotlib",
    "rliable",
    "ray",
)
#: CPU instruction sets that decide which BLAS and numpy kernels run (hence the rounding).
SIMD_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f")


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
    ``models/dagger-dls-paper``), so that a committed report names no machine's folders; else
    absolute."""
    resolved = Path(path).resolve()
    try:
        return resolved.relative_to(CHECKOUT_DIR).as_posix()
    except ValueError:
        return str(resolved)


def _cpuinfo() -> dict[str, str]:
    """The first processor's fields in ``/proc/cpuinfo`` (empty where there is none)."""
    fields: dict[str, str] = {}
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return fields
    for line in text.splitlines():
        if not line.strip():
            break  # the first processor's block ends
        key, _, value = line.partition(":")
        fields[key.strip()] = value.strip()
    return fields


def _blas() -> str | None:
    """numpy's BLAS library and version (``scipy-openblas 0.3.31.188.0``), None if unknown."""
    import numpy as np

    try:
        blas = np.__config__.CONFIG["Build Dependencies"]["blas"]  # type: ignore[attr-defined]
        return f"{blas['name']} {blas['version']}".strip()
    except (AttributeError, KeyError, TypeError):
        return None


def machine() -> dict[str, object]:
    """The machine a report was computed on: CPU model (and its vendor, family, model and
    stepping, which tell CPU generations apart where the model name does not), cores,
    architecture and the instruction sets that pick the BLAS and numpy kernels, operating
    system, numpy's BLAS.

    Episodes are bit for bit the same on the same machine; on another CPU the linear algebra
    (numpy's BLAS, torch's kernels, pybullet) can round differently, so floats agree to rounding
    and an episode on a knife edge can end differently. The package versions are in
    `package_versions`.
    """
    info = _cpuinfo()
    flags = set(info.get("flags", "").split())
    cpu_id = " ".join(
        f"{label} {info[key]}".strip()
        for key, label in (
            ("vendor_id", ""),
            ("cpu family", "family"),
            ("model", "model"),
            ("stepping", "stepping"),
        )
        if info.get(key)
    )
    return {
        "cpu": info.get("model name") or platform.processor() or platform.machine(),
        "cpu_id": cpu_id or None,
        "cores": os.cpu_count(),
        "system": platform.system(),
        "platform": platform.platform(),
        "architecture": platform.machine(),
        "simd": [f for f in SIMD_FLAGS if f in flags] if flags else None,
        "blas": _blas(),
    }


def describe_machine(provenance: Mapping[str, Any]) -> str:
    """One line naming the machine and the numeric packages of a report's provenance
    (``AMD EPYC (AuthenticAMD family 25 model 17 stepping 1), 2 cores, x86_64 with avx2 fma
    avx512f, Linux-6.1-x86_64; Python 3.11.7, numpy 2.4.6 (scipy-openblas 0.3.31), torch
    2.13.0+cpu, pybullet 3.2.7``). Every field is optional, so an older ``results.json`` (fewer
    fields) reads too; "an unknown machine" where it names none."""
    host = provenance.get("machine") or {}
    packages = provenance.get("packages") or {}
    parts = [str(host["cpu"])] if host.get("cpu") else []
    if parts and host.get("cpu_id"):
        parts[0] += f" ({host['cpu_id']})"
    if host.get("cores"):
        parts.append(f"{host['cores']} cores")
    arch = str(host.get("architecture") or "")
    if host.get("simd"):
        arch = f"{arch} with {' '.join(host['simd'])}".strip()
    if arch:
        parts.append(arch)
    if host.get("platform") or host.get("system"):
        parts.append(str(host.get("platform") or host.get("system")))
    versions = []
    for name, label in (("python", "Python"), ("numpy", "numpy"), ("torch", "torch")):
        if packages.get(name):
            versions.append(f"{label} {packages[name]}")
            if name == "numpy" and host.get("blas"):
                versions[-1] += f" ({host['blas']})"
    if packages.get("pybullet"):
        versions.append(f"pybullet {packages['pybullet']}")
    text = ", ".join(parts) or "an unknown machine"
    return f"{text}; {', '.join(versions)}" if versions else text


#: The machine's fields and the packages that decide the last bits of a float here.
REPRODUCTION_MACHINE_KEYS = ("cpu_id", "simd", "blas")
REPRODUCTION_PACKAGES = ("numpy", "torch", "pybullet")


def reproduction_key(
    host: Mapping[str, Any] | None = None, packages: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """What decides the last bits of a float besides the code: the CPU (its identity and its
    instruction sets), numpy's BLAS, and numpy's, torch's and pybullet's versions; this
    machine's where ``host``/``packages`` are not given (a report's ``provenance["machine"]``
    and ``["packages"]`` otherwise). The same code on two machines with equal keys gives the same
    floats bit for bit; with other keys they agree to rounding, and an episode on a knife edge
    can end differently."""
    host = machine() if host is None else host
    packages = package_versions() if packages is None else packages
    return {
        **{
            key: list(host.get(key) or []) if key == "simd" else host.get(key)
            for key in REPRODUCTION_MACHINE_KEYS
        },
        **{name: packages.get(name) for name in REPRODUCTION_PACKAGES},
    }


#: What a report's provenance promises, as the report states it.
REPRODUCIBILITY = (
    "The same command on the same code and machine gives these results bit for bit. On another "
    "machine the floats (capture times, RMSEs) agree to rounding, and an episode on a knife edge, "
    "most often a learned policy's, can end differently and move a rate by one episode. "
    "results.json holds the full provenance: file hashes, seeds, every package version."
)


def provenance_text(provenance: Mapping[str, Any]) -> str:
    """Where and from what code a report was computed, in one sentence (fields that an older
    ``results.json`` lacks are left out); for a merged report (``merged_from``), its source
    reports', those computed on the same code and machine named together."""
    sources = provenance.get("merged_from")
    if not sources:
        return f"Computed{_computed(provenance)}."
    groups: dict[str, list[str]] = {}
    for source in sources:
        groups.setdefault(_computed(source), []).append(str(source.get("report")))
    parts = [f"{', '.join(reports)}, computed{where}" for where, reports in groups.items()]
    return f"Merged from {len(sources)} reports: {'; '.join(parts)}."


def _computed(provenance: Mapping[str, Any]) -> str:
    """`` at commit <sha> on <machine>``: the code and the machine of one computation."""
    git = provenance.get("git") or {}
    code = ""
    if git.get("commit"):
        code = f" at commit {str(git['commit'])[:12]}"
        code += " with uncommitted changes" if git.get("dirty") else ""
    return f"{code} on {describe_machine(provenance)}"


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
