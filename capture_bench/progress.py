"""The progress bar the command-line jobs show while they play episodes (rich, on stderr)."""

from __future__ import annotations

from typing import Any


def episode_bar(name: str, total: int) -> tuple[Any, Any]:
    """A rich ``Progress`` on stderr (description, bar, done/total, elapsed, ETA) and its one
    task, ``"<name>: episodes"`` of ``total``; the caller enters the bar (``with bar:``) and
    advances the task."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        transient=False,
    )
    return bar, bar.add_task(f"{name}: episodes", total=total)
