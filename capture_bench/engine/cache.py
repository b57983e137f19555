"""The target sides and physical-limit bounds already computed, kept by (scenario, seed).

``reset(seed=s)`` draws an episode's target side (a
`capture_bench.task.recording.RecordedEpisode`) and its bound from the scenario and s alone,
so every agent played on a seed can replay what the first one computed: `EpisodeCache` keeps
them, with what a rendered camera saw of the target alone; `DEFAULT_EPISODE_CACHE` is the one
every env uses unless given its own.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping
from typing import Any

from capture_bench.task.episode import EpisodePlan, episode_bounds
from capture_bench.task.observation import TaskDescription
from capture_bench.task.physical_limit import PhysicalLimit
from capture_bench.task.recording import RecordedEpisode
from capture_bench.task.scenarios import Scenario

EpisodeKey = tuple[Scenario, int]  # (scenario, seed)


class EpisodeCache:
    """Target sides and physical-limit bounds already computed, by (scenario, seed).

    ``reset(seed=s)`` draws the episode's target side from the scenario and s alone, before
    anything an agent does, so every agent evaluated on the same seed has the same recording and
    the same bound, each computed once (``benchmarks/bench_reset.py`` times recording an
    episode and its bound). An evaluation runs every agent on a few seeds at a time in one
    worker, so a few recordings suffice (``max_episodes``, least recently used dropped first;
    each holds its episode's arrays, a row per step); bounds are small (``max_limits``, all
    dropped when full).
    Each env uses `DEFAULT_EPISODE_CACHE` unless given another; `clear` empties it.
    """

    def __init__(self, max_episodes: int = 16, max_limits: int = 65_536) -> None:
        self.max_episodes = max_episodes
        self.max_limits = max_limits
        # (episode, np_random's state after recording it)
        self._episodes: OrderedDict[EpisodeKey, tuple[RecordedEpisode, Mapping[str, Any]]] = (
            OrderedDict()
        )
        self._limits: dict[EpisodeKey, PhysicalLimit] = {}
        # What a rendered camera saw of the target alone, by frame, filled as frames are asked
        self._scene_frames: OrderedDict[EpisodeKey, dict[int, Any]] = OrderedDict()

    def recording(self, key: EpisodeKey) -> tuple[RecordedEpisode, Mapping[str, Any]] | None:
        """The recorded episode of ``key`` and the generator's state after recording it, or
        None."""
        found = self._episodes.get(key)
        if found is not None:
            self._episodes.move_to_end(key)
        return found

    def keep_recording(
        self, key: EpisodeKey, episode: RecordedEpisode, rng_state: Mapping[str, Any]
    ) -> None:
        """Keep a complete recording (and the generator's state after it) for ``key``."""
        self._episodes[key] = (episode, rng_state)
        if len(self._episodes) > self.max_episodes:
            self._episodes.popitem(last=False)

    def scene_frames(self, key: EpisodeKey) -> dict[int, Any]:
        """The store of a rendered camera's target-only frames of ``key`` (frame index -> what
        `RenderedSceneCamera` keeps), empty at
        first and filled by the camera; kept for the ``max_episodes`` latest keys."""
        found = self._scene_frames.get(key)
        if found is None:
            found = self._scene_frames[key] = {}
            if len(self._scene_frames) > self.max_episodes:
                self._scene_frames.popitem(last=False)
        else:
            self._scene_frames.move_to_end(key)
        return found

    def counts(self) -> tuple[int, int]:
        """(recordings kept, bounds kept): what the cache holds now."""
        return len(self._episodes), len(self._limits)

    def recorded_keys(self) -> list[EpisodeKey]:
        """The keys of the kept recordings, least recently used first."""
        return list(self._episodes)

    def limit(self, key: EpisodeKey) -> PhysicalLimit | None:
        """The physical-limit bound computed for ``key``, or None."""
        return self._limits.get(key)

    def bound_of(
        self, key: EpisodeKey | None, plan: EpisodePlan, description: TaskDescription
    ) -> PhysicalLimit:
        """The physical-limit bound of ``plan``: the one kept for ``key``, else
        `episode_bounds`' (the one the plan carries since it
        was drawn, or computed now) and kept for ``key`` (None: an unseeded episode, not
        kept)."""
        found = None if key is None else self.limit(key)
        if found is not None:
            return found
        (bound,) = episode_bounds([plan], description)
        if key is not None:
            self.keep_limit(key, bound)
        return bound

    def keep_limit(self, key: EpisodeKey, limit: PhysicalLimit) -> None:
        """Keep a bound for ``key`` (its joint angles become read-only: shared)."""
        if len(self._limits) >= self.max_limits:
            self._limits.clear()
        if limit.theta is not None:
            limit.theta.flags.writeable = False
        self._limits[key] = limit

    def clear(self) -> None:
        """Forget every recording and bound."""
        self._episodes.clear()
        self._limits.clear()
        self._scene_frames.clear()


#: The process-wide cache every env uses unless given its own.
DEFAULT_EPISODE_CACHE = EpisodeCache()
