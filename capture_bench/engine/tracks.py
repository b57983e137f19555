"""The target side of N episodes, step by step: `Tracks`.

Row i of every track holds episode i's `STEP_TRACKS` (time, period, true state, estimate, its
errors, visibility, reachability) from its reset (step 0) to its time limit; the step rule reads
a step's row before and after, the observation the current one. A target side fills them
(`capture_bench.engine.sides`): all at once from a recording, or row by row as steps come.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.task.recording import STEP_TRACKS, RecordedEpisode

_VECTORS = {"position", "velocity", "estimate_position", "estimate_velocity"}
_FLAGS = {"estimate_valid", "visible", "reachable"}


def _dtype(name: str) -> Any:
    if name in _FLAGS:
        return np.bool_
    return np.int8 if name == "estimator_status" else np.float64


class Tracks(dict[str, NDArray]):
    """`STEP_TRACKS` of ``n`` episodes of at most ``steps`` rows each (reset included): a dict of
    arrays (n, steps, ...) by name, (n, steps, 3) for the vectors, zero where nothing was put.

    The tracks of a one-row engine may instead be views of one episode's own arrays (`share`):
    then nothing is copied, at the start or as a live side fills the episode's rows.
    """

    def __init__(self, n: int, steps: int) -> None:
        super().__init__(
            {
                name: np.zeros((n, steps, *((3,) if name in _VECTORS else ())), _dtype(name))
                for name in STEP_TRACKS
            }
        )
        self.steps = steps
        self._shared: RecordedEpisode | None = None  # the episode a one-row track views

    def load(self, row: int, episode: RecordedEpisode) -> None:
        """Copy every row an episode holds into row ``row`` of the tracks."""
        if self._shared is not None:  # back to arrays of the tracks' own
            self._shared = None
            self.update(Tracks(1, self.steps))
        length = episode.time.size
        for name in STEP_TRACKS:
            self[name][row, :length] = getattr(episode, name)

    def share(self, row: int, episode: RecordedEpisode) -> None:
        """Row ``row`` viewing ``episode``'s arrays where the tracks have one row (what is written
        in either is in both; the caller owns the episode), else `load`."""
        if len(self["time"]) != 1:
            self.load(row, episode)
            return
        for name in STEP_TRACKS:
            self[name] = getattr(episode, name)[None]
        self._shared = episode

    def copy_row(self, row: int, k: int, episode: RecordedEpisode) -> None:
        """Copy step ``k`` of an episode into row ``row`` (nothing to copy where the row views
        that episode)."""
        if episode is self._shared:
            return
        for name in STEP_TRACKS:
            self[name][row, k] = getattr(episode, name)[k]
