"""The privileged view of one episode (oracle and tests only): its recording, plan, clock, next
period, true target and physical limit, the same API on the single env and on each sub-env of the
vector env.

`PrivilegedView` holds the API once, over four hooks an env provides (the episode's recording,
its step index, its simulated time, its bound).
[`CaptureEnv`][capture_bench.envs.capture_env.CaptureEnv] is one; `EpisodeView` is row ``i`` of
an `EpisodeRows` (the vector env's ``sub_env(i)``).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from capture_bench.task.episode import EpisodePlan
from capture_bench.task.observation import TaskDescription
from capture_bench.task.physical_limit import PhysicalLimit
from capture_bench.task.recording import RecordedEpisode


class PrivilegedView:
    """The privileged API of one episode, read at the moment it is asked. A subclass provides
    `_view_episode` (the recording, None before reset), `_view_step` (steps since reset),
    `_view_time` (s since reset) and `_view_bound` (the bound of a recording without one)."""

    def _view_episode(self) -> RecordedEpisode | None:
        raise NotImplementedError

    def _view_step(self) -> int:
        raise NotImplementedError

    def _view_time(self) -> float:
        raise NotImplementedError

    def _view_bound(self, episode: RecordedEpisode) -> PhysicalLimit:
        raise NotImplementedError

    def _episode_before(self, what: str) -> RecordedEpisode:
        episode = self._view_episode()
        if episode is None:
            raise RuntimeError(f"call reset() before {what}")
        return episode

    @property
    def recorded_episode(self) -> RecordedEpisode:
        """This episode's target side (privileged)."""
        return self._episode_before("recorded_episode")

    @property
    def plan(self) -> EpisodePlan:
        """This episode's trajectory and control periods, as reset drew them (privileged)."""
        return self._episode_before("plan").plan

    def physical_limit(self) -> PhysicalLimit:
        """The episode's lower bound on capture time (privileged): the recording's, else computed
        when first asked and kept with it (the single env also keeps it in its ``episode_cache``
        by (scenario, seed) after a seeded reset)."""
        episode = self._episode_before("physical_limit()")
        if episode.bound is None:
            episode.bound = self._view_bound(episode)
        return episode.bound

    def true_target_position(self, t: float | NDArray) -> NDArray[np.float64]:
        """X_T(t), global, m (privileged)."""
        return self._episode_before("true_target_position()").plan.trajectory.position(t)

    @property
    def time(self) -> float:
        """Simulated time since reset, s."""
        return self._view_time()

    @property
    def next_control_period(self) -> float:
        """The real period of the next step, s (privileged: the periods are drawn at reset)."""
        episode = self._episode_before("next_control_period")
        return float(episode.plan.periods[self._view_step()])


class EpisodeRows(Protocol):
    """What an env of several episodes gives `EpisodeView` of its row ``i``."""

    @property
    def description(self) -> TaskDescription: ...

    def row_episode(self, i: int) -> RecordedEpisode | None: ...

    def row_step(self, i: int) -> int: ...

    def row_time(self, i: int) -> float: ...


class EpisodeView(PrivilegedView):
    """Row ``index`` of an `EpisodeRows` seen through a single env's privileged API and its public
    ``description``: the same numbers as the single env playing that row's episode. ``unwrapped``
    is the view itself, as an agent built on an env expects. Every recording a row plays carries
    its bound."""

    def __init__(self, rows: EpisodeRows, index: int) -> None:
        self._rows, self.index = rows, index

    @property
    def unwrapped(self) -> EpisodeView:
        return self

    @property
    def description(self) -> TaskDescription:
        """The task's public description."""
        return self._rows.description

    def _view_episode(self) -> RecordedEpisode | None:
        return self._rows.row_episode(self.index)

    def _view_step(self) -> int:
        return self._rows.row_step(self.index)

    def _view_time(self) -> float:
        return self._rows.row_time(self.index)

    def _view_bound(self, episode: RecordedEpisode) -> PhysicalLimit:
        raise AssertionError("every recording a row plays carries its bound")
