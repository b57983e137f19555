"""The files a project is expected to have: a licence and a citation file that agree with
pyproject.toml."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

ROOT = Path(__file__).parents[1]


def test_the_licence_and_the_citation_file_agree_with_the_package():
    pyproject = (ROOT / "pyproject.toml").read_text()  # tomllib is Python 3.11+ only
    version = re.search(r'^version = "([^"]+)"', pyproject, re.M).group(1)
    assert re.search(r'^license = \{ text = "MIT" \}', pyproject, re.M)
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert citation["cff-version"] == "1.2.0" and citation["license"] == "MIT"
    assert str(citation["version"]) == version
    assert citation["title"].startswith("capture-bench")
    assert any("Dong" in a["family-names"] for r in citation["references"] for a in r["authors"])
