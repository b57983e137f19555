"""The documentation: the site builds in strict mode (a broken link, a missing page or a missing API
reference fails), and every generated table of the README and the docs matches its source."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"  # the user's guide checked here
#: The pages with generated tables (``scripts/readme_table.py``), the README first.
GENERATED = (README, ROOT / "docs" / "scenarios.md", ROOT / "docs" / "results" / "leaderboard.md")
README_MAX_LINES = 200
#: What ``mkdocs.yml`` needs: the ``docs`` extra (module names).
DOCS_TOOLCHAIN = ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python")


def _missing_toolchain() -> list[str]:
    missing = []
    for name in DOCS_TOOLCHAIN:
        try:
            found = importlib.util.find_spec(name) is not None
        except ModuleNotFoundError:  # a parent package is missing
            found = False
        if not found:
            missing.append(name)
    return missing


def test_the_site_builds_in_strict_mode(tmp_path):
    missing = _missing_toolchain()
    if missing:
        pytest.skip(
            f"the docs toolchain is not installed ({', '.join(missing)}): pip install -e '.[docs]'"
        )
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},  # Material's banner about MkDocs 2.0
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    assert (tmp_path / "site" / "api" / "envs" / "index.html").is_file()


def test_the_generated_tables_match_their_sources(readme_table, capsys):
    status = readme_table.main(["--check", *map(str, GENERATED)])
    assert status == 0, capsys.readouterr().err


def test_a_stale_table_fails_the_check_and_is_regenerated(readme_table, tmp_path, capsys):
    current = README.read_text()
    row = re.search(r"^\| 1 \| [^|]+ \| (\d\.\d{3}) \|", current, re.M)
    assert row is not None, "the leaderboard table's first row"
    stale = tmp_path / "README.md"
    stale.write_text(current.replace(row.group(0), row.group(0).replace(row.group(1), "0.123"), 1))
    assert readme_table.main(["--check", str(stale)]) == 1
    assert "out of date" in capsys.readouterr().err
    assert readme_table.main([str(stale)]) == 0
    assert stale.read_text() == current


def test_a_file_without_a_generated_table_is_refused(readme_table, tmp_path, capsys):
    (tmp_path / "plain.md").write_text("# nothing generated here\n")
    assert readme_table.main(["--check", str(tmp_path / "plain.md")]) == 2
    assert "no generated block" in capsys.readouterr().err


def test_the_readme_is_a_short_guide_whose_links_resolve():
    text = README.read_text()
    assert len(text.splitlines()) <= README_MAX_LINES
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+://|#", target):
            continue
        assert (ROOT / target.split("#")[0]).exists(), f"{README.name} links to {target}"
