"""Every committed report names the clean commit it was generated from."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
REPORTS = sorted((ROOT / "reports" / "published").glob("*/results.json"))


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30)


@pytest.mark.parametrize("results", REPORTS, ids=lambda p: p.parent.name)
def test_a_committed_report_comes_from_a_clean_ancestor_commit(results):
    git = json.loads(results.read_text())["provenance"]["git"]
    assert git["dirty"] is False, f"{results} was generated from a tree with uncommitted changes"
    assert isinstance(git["commit"], str) and len(git["commit"]) == 40
    if shutil.which("git") is None or _git("rev-parse", "HEAD").returncode != 0:
        pytest.skip("not a git checkout: the commit cannot be looked up")
    if _git("cat-file", "-e", f"{git['commit']}^{{commit}}").returncode != 0:
        if _git("rev-parse", "--is-shallow-repository").stdout.strip() == "true":
            pytest.skip("shallow clone: the report's commit is not in this history")
        pytest.fail(f"{results} names commit {git['commit']}, which this repository lacks")
    ancestor = _git("merge-base", "--is-ancestor", git["commit"], "HEAD")
    assert ancestor.returncode == 0, f"{results}: {git['commit']} is not an ancestor of HEAD"
