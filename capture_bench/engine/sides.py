"""The target's side of N episodes, one interface for every way of producing it: `TargetSides`.

A target side fills an episode's `Tracks` row: the true state, the camera's frame, the
estimate and its errors, reachability (`capture_bench.task.recording.RecordedEpisode`'s
fields). Three strategies:

* `RecordedSides`: nothing of the target's side depends on the actions, so each episode is
  recorded ahead, many at once (`capture_bench.task.recording.record_episodes`: the camera
  vectorised over time, the first frame's cold photogrammetry and the bound over episodes), and
  kept by seed in an `EpisodeCache` so that a seed played again is replayed. With the EKF source
  one batched filter, a row per episode, continues each recording from its first row
  (`LIVE_ESTIMATES_FROM`) one row per step played, so no filter runs past its episode's end;
  its numbers are the recording's of every row, bit for bit (a filter's rows do not depend on
  the other rows of a call). With ``full_horizon`` (the single env's recordings, and a vector
  env's whose cache is shared, as the evaluation's) recordings estimate every row, so that a
  replay runs no filter.
* `LiveSides`: each row computed when its step comes, drawing the camera's noise from the
  episode's generator then, as a plain gymnasium env does (the single env's default).
* `RenderedSides`: the rendered camera's frames show the arm, so each row is computed when its
  step comes, the arm moving as the step moved it (`ArmMotion`); one rendered camera serves
  every episode, each holding its own camera state, and what the camera saw of the target alone
  is kept by seed in the cache.

Both take the next episode of an `EpisodeDraw` (its seed, if any, and the generator it draws
from, advanced exactly as ``CaptureEnv(reuse_target_side=True).reset(seed)`` advances it).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from capture_bench.engine.cache import EpisodeCache, EpisodeKey
from capture_bench.engine.task import CaptureTask
from capture_bench.engine.tracks import Tracks
from capture_bench.sensing.estimator import FilterRows, TargetEstimator
from capture_bench.sensing.scene_camera import RenderedSceneCamera, joint_path
from capture_bench.task.recording import RecordedEpisode, estimate_errors, record_episodes
from capture_bench.task.scenarios import Scenario
from capture_bench.task.target_side import TargetSide

FloatArray = NDArray[np.float64]
#: The rows of a step: an index array, or ``slice(None)``: the one row of a one-row engine.
Rows = NDArray[np.intp] | slice
#: Each row's step (M,), or the one row's step.
Steps = NDArray[np.int64] | int

#: With the EKF source, a recording estimates its first ``LIVE_ESTIMATES_FROM`` rows only (row
#: 0's cold photogrammetry is batched over the recording's episodes); `RecordedSides`' own EKF
#: continues each episode from there, one row per step played, so no filter runs past its
#: episode's end (learned policies end most episodes long before the time limit the recording
#: reaches).
LIVE_ESTIMATES_FROM: int | None = 1


class EpisodeDraw(NamedTuple):
    """Where an episode comes from: its seed (None: unseeded, not kept) and the generator it
    draws from (seeded with it, or a generator continued)."""

    seed: int | None
    rng: np.random.Generator

    def key(self, scenario: Scenario) -> EpisodeKey | None:
        """Where the episode of ``scenario`` is kept: (scenario, seed), None if unseeded."""
        return None if self.seed is None else (scenario, self.seed)


class ArmMotion(NamedTuple):
    """The arms of the stepping rows during a step: joint angles at its start and at its end,
    rad, (M, 3) each (the joint rates are constant within a step)."""

    theta0: FloatArray
    theta1: FloatArray


class TargetSides(Protocol):
    """The target side of N episodes (rows), whatever produces it."""

    #: Whether an episode can be prepared before it is played (no frame shows the arm): the
    #: vector env then records episodes ahead, in batches.
    ahead: bool

    def prepare(self, draws: Sequence[EpisodeDraw]) -> list[RecordedEpisode | EpisodeDraw]:
        """What `begin` takes for the next episode of each draw: its recording for sides that
        prepare `ahead` (each generator advanced as the episode's own draws advance it), the
        draw itself otherwise."""
        ...

    def begin(
        self, rows: Sequence[int], prepared: Sequence[RecordedEpisode | EpisodeDraw], tracks: Tracks
    ) -> list[RecordedEpisode]:
        """Start row ``rows[j]``'s episode from ``prepared[j]``: its tracks' rows filled as far
        as they are known (row 0 at least), its estimator reset or restored. Returns each row's
        episode, its bound set."""
        ...

    def advance(self, rows: Rows, k: Steps, arm: ArmMotion, tracks: Tracks) -> None:
        """Row ``k[j]`` of each stepping row ``rows[j]``'s tracks, the arm having moved as ``arm``
        says during the step."""
        ...

    def close(self) -> None:
        """Release what the sides hold open (a renderer's pybullet world)."""
        ...


class RecordedSides:
    """Target sides recorded ahead and kept by seed (see the module docstring).

    Args:
        task: the task (scenario, camera, features, description).
        n: the number of rows.
        cache: where recordings of seeded episodes are kept and found again.
        full_horizon: recordings estimate every row to the time limit (where the cache is shared:
            a replay then runs no filter); else the EKF continues each recording live, one row
            per step played (`LIVE_ESTIMATES_FROM`). The same numbers either way.
    """

    ahead = True

    def __init__(self, task: CaptureTask, n: int, cache: EpisodeCache, full_horizon: bool) -> None:
        sc = task.scenario
        self.task, self.cache = task, cache
        self._full_horizon = full_horizon
        self._ekf: TargetEstimator | None = None
        if sc.estimator.source == "ekf" and LIVE_ESTIMATES_FROM is not None:
            self._ekf = TargetEstimator(
                n, task.camera.model, task.features, **sc.estimator_settings()
            )
            self._images = np.full(
                (n, task.steps, task.features.shape[0], 2), np.nan
            )  # each row's frames, for its live filter
        # The first row of each episode that the live filter estimates (the recording's
        # continuation step; past the episode's end where the recording holds every row).
        self._live_from = np.zeros(n, dtype=np.int64)

    def prepare(self, draws: Sequence[EpisodeDraw]) -> list[RecordedEpisode | EpisodeDraw]:
        """The next episode of each draw: from the cache where its seed was recorded before (the
        generator then set to its state after that recording), else recorded now, all together,
        and kept by seed; each bounded."""
        task = self.task
        keys = [draw.key(task.scenario) for draw in draws]
        found: list[RecordedEpisode | None] = []
        for key, draw in zip(keys, draws, strict=True):
            hit = None if key is None else self.cache.recording(key)
            if hit is not None:
                draw.rng.bit_generator.state = hit[1]
            found.append(None if hit is None else hit[0])
        missing = [j for j, episode in enumerate(found) if episode is None]
        rngs = [draws[j].rng for j in missing]
        recorded: list[RecordedEpisode] = []
        if missing:
            recorded = record_episodes(
                task.scenario,
                task.camera,
                task.features,
                task.description,
                rngs,
                estimated_steps=None if self._full_horizon else LIVE_ESTIMATES_FROM,
            )
        for j, episode in zip(missing, recorded, strict=True):
            found[j] = episode
            if (key := keys[j]) is not None:
                self.cache.keep_recording(key, episode, draws[j].rng.bit_generator.state)
        episodes: list[RecordedEpisode | EpisodeDraw] = []
        for episode in found:
            assert episode is not None  # found in the cache or recorded now
            episodes.append(episode)
        return episodes

    def begin(
        self, rows: Sequence[int], prepared: Sequence[RecordedEpisode | EpisodeDraw], tracks: Tracks
    ) -> list[RecordedEpisode]:
        filters: list[tuple[int, FilterRows]] = []
        episodes = []
        for i, episode in zip(rows, prepared, strict=True):
            assert isinstance(episode, RecordedEpisode)  # prepared ahead
            if episode.continuation is None:  # every row recorded: read in place where one row
                tracks.share(i, episode)
            else:  # the live filter writes the rows past the recording's
                tracks.load(i, episode)
            self._live_from[i] = episode.time.size
            if episode.continuation is not None:
                self._images[i, : episode.time.size] = episode.images
                self._live_from[i] = episode.continuation.step
                filters.append((i, episode.continuation.filter))
            episodes.append(episode)
        if filters:
            assert self._ekf is not None  # only the EKF's recordings stop short
            filter_rows, states = zip(*filters, strict=True)
            self._ekf.restore(list(filter_rows), FilterRows.stack(list(states)))
        return episodes

    def advance(self, rows: Rows, k: Steps, arm: ArmMotion, tracks: Tracks) -> None:
        """The live filter's rows (recorded rows are in the tracks already)."""
        if self._ekf is None:
            return
        if isinstance(rows, slice):
            rows, k = np.zeros(1, dtype=np.intp), np.array([k])
        if rows.size:
            live = k >= self._live_from[rows]
            if live.any():
                self._estimate(rows[live], k[live], tracks)

    def _estimate(self, idx: NDArray[np.intp], k: NDArray[np.int64], tracks: Tracks) -> None:
        """Row k[j] of the estimate tracks of row idx[j], each at its own step (the row after
        the last one its filter estimated): one update of the live EKF with those frames (what
        the recording's batched EKF gives the row: a filter's numbers do not depend on which
        others update with it), then the errors and NEES as `estimate_errors` derives them."""
        ekf = self._ekf
        assert ekf is not None
        n = self._images.shape[0]
        images = np.full((n, *self._images.shape[2:]), np.nan)
        images[idx] = self._images[idx, k]
        dt = np.zeros(n)
        dt[idx] = tracks["dt"][idx, k]
        active = np.zeros(n, dtype=bool)
        active[idx] = True
        out = ekf.update(images, dt, active)
        position, velocity, valid = out.position[idx], out.velocity[idx], out.valid[idx]
        tracks["estimate_position"][idx, k] = position
        tracks["estimate_velocity"][idx, k] = velocity
        tracks["estimate_valid"][idx, k] = valid
        tracks["estimator_status"][idx, k] = out.status[idx]
        errors = estimate_errors(
            position,
            velocity,
            out.covariance[idx],
            valid,
            tracks["position"][idx, k],
            tracks["velocity"][idx, k],
        )
        for name, value in zip(("position_error", "velocity_error", "nees"), errors, strict=True):
            tracks[name][idx, k] = value

    def close(self) -> None:
        pass


class LiveSides:
    """Target sides computed row by row as steps come, each row a live
    `capture_bench.task.target_side.TargetSide` with its own one-row estimator and camera
    state, drawing the camera's noise from its episode's generator step by step, as a plain
    gymnasium env does. Nothing is kept: the episode's bound is left to be asked for."""

    ahead = False

    def __init__(self, task: CaptureTask, n: int) -> None:
        sc = task.scenario
        self.task = task
        #: Each row's estimator (one row; reset at each episode's start).
        self.estimators = [
            TargetEstimator(
                1,
                task.camera.model,
                task.features,
                source=sc.estimator.source,
                **sc.estimator_settings(),
            )
            for _ in range(n)
        ]
        self.sides: list[TargetSide | None] = [None] * n

    def prepare(self, draws: Sequence[EpisodeDraw]) -> list[RecordedEpisode | EpisodeDraw]:
        return list(draws)

    def begin(
        self, rows: Sequence[int], prepared: Sequence[RecordedEpisode | EpisodeDraw], tracks: Tracks
    ) -> list[RecordedEpisode]:
        """Each row's episode drawn from its draw's generator (`TargetSide.draw`), row 0
        computed."""
        home = self.task.description.arm.home
        episodes = []
        for i, draw in zip(rows, prepared, strict=True):
            assert isinstance(draw, EpisodeDraw)
            side = self._draw(i, draw)
            side.arm_at = lambda _t: home
            episode = side.through(0)
            self.sides[i] = side
            tracks.share(i, episode)  # the side fills its episode's rows
            episodes.append(episode)
        return episodes

    def _draw(self, i: int, draw: EpisodeDraw) -> TargetSide:
        task = self.task
        return TargetSide.draw(
            task.scenario, task.camera, self.estimators[i], task.features, draw.rng
        )

    def advance(self, rows: Rows, k: Steps, arm: ArmMotion, tracks: Tracks) -> None:
        """Row k[j] of row rows[j]'s live side, copied into the tracks."""
        for j, (i, step) in enumerate(_row_steps(rows, k)):
            side = self.sides[i]
            assert side is not None
            self._before_row(side, j, i, step, arm, tracks)
            tracks.copy_row(i, step, side.through(step))

    def _before_row(
        self, side: TargetSide, j: int, i: int, k: int, arm: ArmMotion, tracks: Tracks
    ) -> None:
        """What a row needs before its step ``k`` is computed (nothing: the camera sees the
        target alone)."""

    def close(self) -> None:
        pass


class RenderedSides(LiveSides):
    """Live target sides whose frames come from one `RenderedSceneCamera` (they show the arm, as
    it moved during the step: `ArmMotion`); each row's camera state is its own. Each episode
    is bounded at its start (kept by seed in the cache), and with ``keep_frames`` what the
    camera saw of the target alone is kept by seed in the cache too."""

    def __init__(
        self, task: CaptureTask, n: int, cache: EpisodeCache, keep_frames: bool = True
    ) -> None:
        super().__init__(task, n)
        self.cache, self.keep_frames = cache, keep_frames
        self.camera: RenderedSceneCamera | None = RenderedSceneCamera.for_scenario(task.scenario)

    def begin(
        self, rows: Sequence[int], prepared: Sequence[RecordedEpisode | EpisodeDraw], tracks: Tracks
    ) -> list[RecordedEpisode]:
        episodes = super().begin(rows, prepared, tracks)
        task = self.task
        for draw, episode in zip(prepared, episodes, strict=True):
            assert isinstance(draw, EpisodeDraw)
            episode.bound = self.cache.bound_of(
                draw.key(task.scenario), episode.plan, task.description
            )
        return episodes

    def _draw(self, i: int, draw: EpisodeDraw) -> TargetSide:
        assert self.camera is not None
        task = self.task
        key = draw.key(task.scenario)
        store = None if key is None or not self.keep_frames else self.cache.scene_frames(key)
        return TargetSide.draw(
            task.scenario, self.camera, self.estimators[i], task.features, draw.rng, store
        )

    def _before_row(
        self, side: TargetSide, j: int, i: int, k: int, arm: ArmMotion, tracks: Tracks
    ) -> None:
        """The arm's path during step ``k`` (the frame shows it)."""
        times = tracks["time"]
        t0, t1 = float(times[i, k - 1]), float(times[i, k])
        side.arm_at = joint_path(arm.theta0[j], arm.theta1[j], t0, t1)

    def close(self) -> None:
        if self.camera is not None:
            self.camera.close()
            self.camera = None


def _row_steps(rows: Rows, k: Steps) -> list[tuple[int, int]]:
    """(row, step) pairs of a step's rows: index arrays with a step each, or every row of a
    one-row engine (``slice(None)``) at step ``k``."""
    if isinstance(rows, slice):
        return [(0, int(k))]
    return list(zip(rows.tolist(), np.asarray(k).tolist(), strict=True))


def target_sides(
    task: CaptureTask, n: int, cache: EpisodeCache, *, recorded: bool = True, full_horizon: bool
) -> TargetSides:
    """The target sides of ``n`` rows of ``task``: rendered where the scenario's camera renders
    (the target-only frames kept in the cache if ``recorded``), else recorded ahead if
    ``recorded`` (``full_horizon``: `RecordedSides`' own), else live."""
    if task.scenario.camera.mode == "rendered":
        return RenderedSides(task, n, cache, keep_frames=recorded)
    if recorded:
        return RecordedSides(task, n, cache, full_horizon)
    return LiveSides(task, n)
