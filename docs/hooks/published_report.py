"""mkdocs hook: the published leaderboard report, ``reports/published/default/``, is part of the
site under ``results/report/`` (its figures, episode GIFs, tables and the self-contained
``leaderboard.html``), taken from the report's folder at every build, so the pages show the figures
of the committed report and nothing of it is copied into ``docs/``. A page links them as
``results/report/<file>`` (relative to its own place), and mkdocs' strict link validation checks
those links like any other.

The report's ``leaderboard.md`` is left out: mkdocs would make it a page.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File, Files

#: The published report, relative to the folder of ``mkdocs.yml``.
REPORT = Path("reports") / "published" / "default"
#: Where its files are in the site.
SITE_FOLDER = "results/report"
#: The report's files that the site does not carry (a Markdown file would become a page).
LEFT_OUT_SUFFIXES = frozenset({".md"})


def report_folder(config: Any) -> Path:
    """The published report's folder of this configuration's checkout."""
    return Path(config.config_file_path).resolve().parent / REPORT


def report_files(folder: Path) -> list[Path]:
    """The report's files the site carries, by name."""
    return sorted(
        path
        for path in folder.iterdir()
        if path.is_file() and path.suffix not in LEFT_OUT_SUFFIXES and not path.name.startswith(".")
    )


def on_files(files: Files, config: Any) -> Files:
    folder = report_folder(config)
    if not (folder / "leaderboard.html").is_file():
        raise PluginError(
            f"the published report {folder} has no leaderboard.html: "
            "python evaluate.py --publish writes it"
        )
    for path in report_files(folder):
        files.append(File.generated(config, f"{SITE_FOLDER}/{path.name}", abs_src_path=str(path)))
    return files


def on_serve(server: Any, config: Any, builder: Any) -> Any:
    """``mkdocs serve`` rebuilds when the report changes."""
    server.watch(str(report_folder(config)))
    return server
