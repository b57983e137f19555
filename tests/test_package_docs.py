"""Every package under ``capture_bench/`` says what it is: its ``__init__.py`` opens with a
module docstring that is not empty (read with `ast`, nothing imported)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def undocumented_packages(package: Path) -> list[str]:
    """The packages under ``package`` (itself included) whose ``__init__.py`` has no docstring or
    an empty one, as paths relative to ``package``'s parent."""
    found = []
    for init in sorted(package.rglob("__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8")))
        if not (doc and doc.strip()):
            found.append(str(init.parent.relative_to(package.parent)))
    return found


def test_every_package_has_a_docstring() -> None:
    missing = undocumented_packages(ROOT / "capture_bench")
    assert not missing, f"packages without a module docstring in __init__.py: {missing}"


def test_the_check_finds_a_package_without_one(tmp_path: Path) -> None:
    files = {
        "pkg/__init__.py": '"""A package."""\n',
        "pkg/empty/__init__.py": "",
        "pkg/blank/__init__.py": '"""   """\nimport os\n',
        "pkg/late/__init__.py": 'import os\n"""Not a docstring: it comes after code."""\n',
        "pkg/fine/__init__.py": '"""What it holds."""\n',
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    assert undocumented_packages(tmp_path / "pkg") == ["pkg/blank", "pkg/empty", "pkg/late"]
