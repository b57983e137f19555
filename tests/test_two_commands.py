"""README's two commands in sequence, on a copy of this checkout: the main job
(``python evaluate.py``) writes the user's own report and compares it with the published one,
and after it the published report, README's table (what ``tests/test_docs.py`` checks) and the
models are as they were, and the checkout is clean."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
#: The default suite made small enough for a test: the same file, fewer agents and episodes.
SMALL_DEFAULT = """\
description: the default suite, small
agents: [incremental_ik, random, models/dagger-dls-paper]
scenarios: all
episodes: 2
reference: incremental_ik
videos: false
"""


def _git(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["git", "-c", "user.name=t", "-c", "user.email=t@localhost", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )


@pytest.fixture(scope="module")
def checkout(tmp_path_factory) -> Path:
    """A clean git checkout of this tree's files (tracked and not ignored), with the small
    default suite committed."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    listed = _git(ROOT, "ls-files", "-z", "--cached", "--others", "--exclude-standard").stdout
    copy = tmp_path_factory.mktemp("checkout") / "capture-bench"
    for name in filter(None, listed.split("\0")):
        source = ROOT / name
        if source.is_file():
            (copy / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, copy / name)
    (copy / "configs" / "suites" / "default.yaml").write_text(SMALL_DEFAULT)
    _git(copy, "init", "-q")
    _git(copy, "add", "-A")
    _git(copy, "commit", "-q", "-m", "a user's clone")
    return copy


def _run(copy: Path, *argv: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAPTURE_BENCH_")}
    return subprocess.run(
        [sys.executable, *argv], cwd=copy, capture_output=True, text=True, timeout=600, env=env
    )


def test_the_main_job_then_the_checks_leave_a_clean_checkout(checkout):
    published = checkout / "reports" / "published" / "default"
    before = {p.name: p.read_bytes() for p in published.iterdir()}
    done = _run(checkout, "evaluate.py", "--workers", "2")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "uncommitted changes" not in done.stderr  # a clean clone stays clean while it runs
    assert "against the published report reports/published/default/" in done.stdout
    assert (checkout / "reports" / "default" / "reproduction.md").is_file()
    assert {p.name: p.read_bytes() for p in published.iterdir()} == before
    table = _run(checkout, "scripts/readme_table.py", "--check")
    assert table.returncode == 0, table.stdout + table.stderr
    assert _git(checkout, "status", "--porcelain").stdout == ""
