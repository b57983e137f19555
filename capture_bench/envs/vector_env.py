"""``CaptureVectorEnv``: N capture episodes stepped together with stacked numpy.

``gymnasium.make_vec("CaptureBench/Paper-v1", num_envs=64)`` builds one (the registered
``vector_entry_point``). Sub-env i behaves as ``CaptureEnv(scenario, reuse_target_side=True)``
seeded like gymnasium's ``SyncVectorEnv`` seeds its i-th env, with next-step autoreset (or none,
``autoreset_mode=AutoresetMode.DISABLED``): the same episodes, the same observations, rewards and
``info``, bit for bit (both step an `capture_bench.engine.engine.EpisodeEngine`, and a row's numbers
do not depend on the other rows).

What it is: seeds, autoreset and gymnasium's vector ``info`` around one
`capture_bench.engine.engine.EpisodeEngine` of N rows, which holds the episodes and steps them
(the arm's side for all rows together; the target's side recorded ahead, many episodes at once,
with one batched filter continuing each recording one row per step played,
`capture_bench.engine.sides`; the task's rules, `capture_bench.task.step_rule.StepRule`, the
code ``CaptureEnv`` runs for its one episode). Since nothing on the target's side of a step
depends on the actions, each sub-env's next episodes are recorded ahead in batches (unless the
camera renders the arm: then each row is computed as its step comes).

Differences from N single envs, all in the format only:

* ``info`` is gymnasium's vector form: each key holds an (N,) array and ``_key`` marks the sub-envs
  that report it. ``capture_time``, ``capture_time_estimated``, the capture instant's
  ``distance_at_capture``, ``relative_speed_at_capture`` and ``relative_speed_max_over_hold``, and
  ``physical_limit_time`` are NaN where the single env gives None (``physical_limit_time`` is
  marked only where an episode ended);
  ``failure`` and ``estimator_status`` are object arrays of the single env's values. A sub-env
  that autoresets reports its reset ``info`` (``time``, ``distance``) that step.
* No rendering; the privileged API of sub-env i is ``sub_env(i)`` (the oracle's view).
* With ``observation_source="pixels"`` one renderer, with one pybullet world, draws every
  sub-env's image in turn (`WorkspaceImager`),
  stacked as ``image`` (N, 3, H, W) beside ``state`` (N, 7).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from capture_bench.engine.arm import ArmSide
from capture_bench.engine.cache import EpisodeCache
from capture_bench.engine.engine import EpisodeEngine
from capture_bench.engine.sides import EpisodeDraw, target_sides
from capture_bench.engine.task import CaptureTask, check_actions
from capture_bench.engine.view import EpisodeView
from capture_bench.envs.core import Observation, TaskAccess
from capture_bench.task.recording import RecordedEpisode
from capture_bench.task.scenarios import Scenario
from capture_bench.task.step_rule import OPTIONAL_KEYS

FloatArray = NDArray[np.float64]
RECORD_AHEAD = 2  # episodes recorded ahead per sub-env (batches of ~num_envs episodes)
#: With seed sources, each sub-env's queue is topped up to ``ceil(RECORD_BATCH / num_envs)``
#: episodes (at least ``RECORD_AHEAD``), so that a batch holds ~``RECORD_BATCH / 2`` episodes or
#: more even with few sub-envs: the estimator's cost per episode-step falls with the batch
#: (``benchmarks/bench_estimator_batch.py``; figures in docs/speed.md). Memory: each queued
#: recorded episode's arrays, a row per step.
RECORD_BATCH = 64


class EpisodeSeedSource(Protocol):
    """A stream of episode seeds (e.g. `capture_bench.training.seeds.TrainingSeedDraw`)."""

    def next(self) -> int:
        """The seed of the next episode."""
        ...


AUTORESET_MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.DISABLED)


class CaptureVectorEnv(TaskAccess, VectorEnv):
    """N [`CaptureEnv`][capture_bench.envs.capture_env.CaptureEnv] episodes of one scenario, stepped
    together.

    Args:
        num_envs: number of sub-envs N.
        scenario: a shipped name, a YAML path or a ``Scenario`` (as ``CaptureEnv``).
        observation_source: ``"ekf"``, ``"photogrammetry"`` or ``"truth"`` (default: the
            scenario's). ``"photogrammetry"`` runs its estimator episode by episode (slower).
            ``"pixels"``: the camera's image and the arm's state, as ``CaptureEnv``'s; the
            scenario's estimator runs for ``info``.
        reward: ``"dense"`` or ``"sparse"``.
        image_size: with ``"pixels"``, the image's (width, height), pixels (default None:
            (84, 84)); with any other source, ``ConfigError`` (as ``CaptureEnv``).
        frame_stack: with ``"pixels"``, the last k images along the channels, as
            ``CaptureEnv``'s; each sub-env's stack restarts with its episode.
        ee_crop: the end-effector crop's side, pixels, as ``CaptureEnv``'s.
        ee_crop_scale: sensor pixels per crop pixel, as ``CaptureEnv``'s.
        image_supersample: samples per image pixel, a side, as ``CaptureEnv``'s.
        ee_crop_supersample: the same for the crop, as ``CaptureEnv``'s.
        reuse_target_side: must be True (accepted so that ``make_vec(id, n,
            reuse_target_side=True)`` means the same for every vectorization mode).
        render_mode: must be None (the vector env does not render).
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (default) or ``AutoresetMode.DISABLED``
            (or their values, ``"NextStep"``, ``"Disabled"``); ``metadata["autoreset_mode"]``
            says which.
        episode_cache: where recordings of seeded episodes are kept by (scenario, seed) and
            found again; a cache given here is shared (with other envs, ``CaptureEnv`` too, as
            the evaluation shares one between its envs): its recordings then estimate every
            row to the time limit, so that a replay runs no filter. Default: the env's own, the
            latest ``max(16, 2 * num_envs)``, whose recordings the env's own filter continues
            one row per step played. The episodes are the same either way.

    Spaces, rewards, termination and ``info`` are ``CaptureEnv``'s (see its docstring), batched;
    see the module docstring for the format of ``info``. Autoreset, as gymnasium's
    ``SyncVectorEnv`` does it:

    * ``NEXT_STEP``: the step after a sub-env's episode ends resets it and returns its first
      observation, reward 0 and no termination.
    * ``DISABLED``: an ended sub-env stays ended until the caller resets it, alone or with
      others, with ``reset(seed=..., options={"reset_mask": mask})``. Until then ``step()``
      leaves it as it is: its row of the actions is ignored, its observation is that of its
      last step, its reward 0, ``terminated`` and ``truncated`` False, and no ``info`` key is
      marked for it (``SyncVectorEnv`` instead asserts that no ended sub-env is stepped; code
      written for it runs here unchanged). ``reset(seed=[s0, s1, ...])`` plays, in sub-env i,
      exactly the episode of ``CaptureEnv(reuse_target_side=True).reset(seed=s_i)``: a batch of
      episodes of different lengths, each played to its end once, as the evaluation plays
      them.

    Recordings of seeded episodes are kept by seed (`episode_cache`), so resetting with
    seeds played before (the evaluation plays every agent on the same seeds) replays their
    target side instead of recording it again; the episodes are the same either way.

    Episodes come from each sub-env's own generator, as gymnasium seeds them, unless
    [`set_episode_seeds`][capture_bench.envs.vector_env.CaptureVectorEnv.set_episode_seeds] gives
    each sub-env a stream of episode seeds (what SB3 training
    wants: every episode explicitly seeded, yet recorded ahead in batches).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | Scenario = "paper",
        *,
        observation_source: str | None = None,
        reward: str = "dense",
        reuse_target_side: bool = True,
        render_mode: str | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        episode_cache: EpisodeCache | None = None,
        image_size: tuple[int, int] | None = None,
        frame_stack: int | None = None,
        ee_crop: int | None = None,
        ee_crop_scale: int | None = None,
        image_supersample: int | None = None,
        ee_crop_supersample: int | None = None,
    ) -> None:
        if not reuse_target_side:
            raise ValueError(
                "CaptureVectorEnv always records each episode's target side at reset "
                "(reuse_target_side=True); for live single envs use "
                "gymnasium.make_vec(..., vectorization_mode='sync')"
            )
        if render_mode is not None:
            raise ValueError(
                f"CaptureVectorEnv does not render (render_mode={render_mode!r}); use "
                "gymnasium.make_vec(..., vectorization_mode='sync', render_mode=...)"
            )
        if int(num_envs) != num_envs or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        mode = _autoreset_mode(autoreset_mode)
        self.task = task = CaptureTask(
            scenario,
            observation_source=observation_source,
            reward=reward,
            image_size=image_size,
            frame_stack=frame_stack,
            ee_crop=ee_crop,
            ee_crop_scale=ee_crop_scale,
            image_supersample=image_supersample,
            ee_crop_supersample=ee_crop_supersample,
        )  # checks ``observation_source``, ``reward``, ``image_size`` and the pixel options
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        self.render_mode = None
        self.num_envs = n = int(num_envs)
        self.single_observation_space = task.single_observation_space
        self.single_action_space = task.single_action_space
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        #: Recordings of seeded episodes by (scenario, seed), replayed when a seed comes again.
        self.episode_cache = (
            EpisodeCache(max_episodes=max(16, 2 * n), max_limits=0)
            if episode_cache is None
            else episode_cache
        )
        # One pybullet world answers every sub-env's collision query in turn (a world is most of
        # an env's memory, and one per sub-env would multiply it): the joints are set before each
        # query.
        self._engine: EpisodeEngine | None = EpisodeEngine(
            task,
            n,
            target_sides(task, n, self.episode_cache, full_horizon=episode_cache is not None),
            ArmSide(task.features, task.description.arm),
        )
        self._rngs: list[np.random.Generator | None] = [None] * n
        # The seed of the generator's first episode, until it is recorded (None: unseeded).
        self._generator_seeds: list[int | None] = [None] * n
        self._sources: list[EpisodeSeedSource] | None = None
        # (episode seed or None, episode) recorded ahead, in the order each sub-env plays them
        self._queues: list[deque[tuple[int | None, RecordedEpisode]]] = [deque() for _ in range(n)]
        self._episode_seeds: list[int | None] = [None] * n
        # NEXT_STEP: reset these sub-envs at the next step; DISABLED: they wait for reset()
        self._ended = np.ones(n, dtype=bool)
        self._started = False

    # -- gymnasium API --------------------------------------------------------------------------
    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[Observation, dict[str, Any]]:
        """Reset the sub-envs (``options["reset_mask"]``: only those marked).

        ``seed``: an int s seeds sub-env i with s + i, as ``SyncVectorEnv`` does; a list gives
        one seed (or None) per sub-env. An unseeded sub-env continues its own generator (what
        was recorded ahead from an old generator is discarded), or, after
        [`set_episode_seeds`][capture_bench.envs.vector_env.CaptureVectorEnv.set_episode_seeds],
        plays the next episode of its seed source; there an explicit
        seed plays that seed's episode once, and the source's stream continues after it.
        """
        n = self.num_envs
        mask = np.ones(n, dtype=bool)
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (n,):
                raise ValueError(f"options['reset_mask'] must have shape ({n},), got {mask.shape}")
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = [None if s is None else int(s) for s in seed]
            if len(seeds) != n:
                raise ValueError(f"seed must be an int, None or a list of {n} seeds, got {seed!r}")
        if not self._started and not mask.all():
            raise ValueError("the first reset() must reset every sub-env (no reset_mask)")
        envs = np.flatnonzero(mask)
        explicit: dict[int, int] = {}  # with seed sources: sub-env -> the seed it plays now
        if self._sources is not None:
            explicit = {i: s for i in envs.tolist() if (s := seeds[i]) is not None}
            for s in explicit.values():
                seeding.np_random(s)  # a bad seed raises before anything changes
        else:
            fresh = {  # every new generator first, so that a bad seed changes nothing
                i: seeding.np_random(seeds[i])[0]
                for i in envs.tolist()
                if seeds[i] is not None or self._rngs[i] is None
            }
            for i, rng in fresh.items():
                self._rngs[i] = rng
                self._generator_seeds[i] = seeds[i]
                self._queues[i].clear()  # recorded from the old generator
        self._start(envs, explicit)
        self._ended[envs] = False
        self._started = True
        return self._live_engine().observe(), self._reset_info(envs)

    def step(
        self, actions: NDArray
    ) -> tuple[Observation, FloatArray, NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:
        """Step every sub-env with its row of ``actions``, shape (num_envs, 3), in [-1, 1].

        Out-of-range values are clipped; a wrong shape, a non-numeric dtype or a NaN/infinite
        entry raises ``ValueError`` naming it
        (`capture_bench.engine.task.check_actions`, the rule of `CaptureEnv`),
        and nothing is stepped. After ``close()``: ``RuntimeError``.
        """
        if self._engine is None:
            raise RuntimeError("CaptureVectorEnv.step() called after close(); the env is closed")
        if not self._started:
            raise RuntimeError("CaptureVectorEnv.step() called before reset(); call reset() first")
        n = self.num_envs
        a = check_actions(actions, (n, 3), "actions")
        stepping = np.flatnonzero(~self._ended)
        resetting = np.flatnonzero(self._ended)
        if self.autoreset_mode == AutoresetMode.DISABLED:
            resetting = resetting[:0]  # ended sub-envs stay as they are
        if resetting.size:
            self._start(resetting, {})
        rewards = np.zeros(n)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        info = self._step(stepping, a[stepping], rewards, terminated, truncated)
        obs = self._engine.observe()
        if resetting.size:
            for key, value in self._reset_info(resetting).items():
                if key.startswith("_"):
                    info[key] = info.get(key, np.zeros(n, dtype=bool)) | value
                else:
                    info[key] = np.where(self._mask(resetting), value, info[key])
            self._ended[resetting] = False
        self._ended[stepping] = terminated[stepping] | truncated[stepping]
        return obs, rewards, terminated, truncated, info

    def estimate_observation(self) -> NDArray[np.float32]:
        """Every sub-env's estimate-fed observation at its current step, (num_envs, 16): the
        observation of the same env made with the scenario's estimator as its source; with
        ``observation_source="pixels"``, the estimate behind ``info``, what an analytic teacher
        of a pixel student reads (privileged: the agent sees the pixels)."""
        return self._live_engine().observe_estimate()

    def true_observation(self) -> NDArray[np.float32]:
        """Every sub-env's observation at its current step with the target's true position and
        velocity in place of the estimate, (num_envs, 16) (privileged: what an asymmetric
        critic reads in training, `capture_bench.training.common.asymmetric`)."""
        return self._live_engine().observe_truth()

    def true_features(self) -> NDArray[np.float64]:
        """Every sub-env's target feature points (the marker centres) at its current step,
        global, m, (num_envs, F, 3) (privileged: the truth behind the image; `WorkspaceImager.
        view_points` places them in a view's pixels, `capture_bench.sensing.workspace_image`)."""
        return self._live_engine().true_features()

    def true_image_points(self) -> NDArray[np.float64]:
        """Every sub-env's target feature points in the wide image at its current step,
        [column, row] in its pixels, (num_envs, F, 2) (privileged: the keypoints a pixel
        student's reader is fitted to in DAgger, `capture_bench.training.common.imitation`)."""
        return self._live_engine().true_image_points()

    def set_episode_seeds(self, sources: Sequence[EpisodeSeedSource] | None) -> None:
        """Seed every later episode of sub-env i with ``sources[i].next()`` (None: back to each
        sub-env's own generator, gymnasium's rule).

        The seeds are drawn when the episodes are recorded, ahead and in batches, and sub-env i
        plays them in the order drawn, so its episodes are those of single envs reset with
        those seeds one by one (``CaptureEnv.reset(seed=s)``). Everything recorded ahead is
        discarded (it came from the old streams): call this again after re-seeding a source.
        Takes effect at each sub-env's next reset;
        [`episode_seeds`][capture_bench.envs.vector_env.CaptureVectorEnv.episode_seeds] tells the
        seed of
        each sub-env's current episode.
        """
        if sources is not None:
            sources = list(sources)
            usable = all(callable(getattr(source, "next", None)) for source in sources)
            if len(sources) != self.num_envs or not usable:
                raise ValueError(
                    f"set_episode_seeds takes None or {self.num_envs} seed sources (objects "
                    f"with next() -> int), got {sources!r}"
                )
        else:  # every sub-env needs a generator again (unseeded where it never had one)
            for i, rng in enumerate(self._rngs):
                if rng is None:
                    self._rngs[i] = seeding.np_random(None)[0]
                    self._generator_seeds[i] = None
        self._sources = sources
        for queue in self._queues:
            queue.clear()

    @property
    def episode_seeds(self) -> list[int | None]:
        """The seed of each sub-env's current episode: the explicit or the source's seed it
        was reset with, None where the episode continues its sub-env's generator."""
        return list(self._episode_seeds)

    def sub_env(self, i: int) -> EpisodeView:
        """Sub-env ``i`` seen through a single env's privileged API (a privileged agent's view,
        the oracle's), read live from this env."""
        if not 0 <= i < self.num_envs:
            raise IndexError(f"sub-env {i} of {self.num_envs}")
        return EpisodeView(self, i)

    def row_episode(self, i: int) -> RecordedEpisode | None:
        """Sub-env ``i``'s current recording (privileged), None before its first reset."""
        return self._live_engine().episodes[i]

    def row_step(self, i: int) -> int:
        """Steps since sub-env ``i``'s reset."""
        return int(self._live_engine().steps[i])

    def row_time(self, i: int) -> float:
        """Simulated time since sub-env ``i``'s reset, s."""
        return self._live_engine().time(i)

    def close_extras(self, **kwargs: Any) -> None:
        if self._engine is not None:
            self._engine.close()
            self._engine = None

    def _live_engine(self) -> EpisodeEngine:
        if self._engine is None:
            raise RuntimeError("CaptureVectorEnv is closed")
        return self._engine

    # -- episodes -------------------------------------------------------------------------------
    def _start(self, envs: NDArray[np.intp], explicit: dict[int, int]) -> None:
        """Begin the next episode of each sub-env in ``envs``: that of the seed ``explicit[i]``
        where given (seed sources only), else the next one (recorded ahead where the target
        sides allow it, recording a batch for every sub-env short of episodes when one of them
        has none)."""
        engine = self._live_engine()
        if not engine.sides.ahead:
            draws = [self._draw(i, explicit) for i in envs.tolist()]
            engine.begin(envs, engine.prepare(draws))
            for i, draw in zip(envs.tolist(), draws, strict=True):
                self._episode_seeds[i] = draw.seed
            return
        ahead: list[tuple[int, EpisodeDraw]] = []
        if any(i not in explicit and not self._queues[i] for i in envs.tolist()):
            ahead = self._to_record(envs)
        now = [(i, EpisodeDraw(s, seeding.np_random(s)[0])) for i, s in explicit.items()]
        recorded = engine.prepare([draw for _, draw in now + ahead])
        for (i, draw), episode in zip(ahead, recorded[len(now) :], strict=True):
            assert isinstance(episode, RecordedEpisode)
            self._queues[i].append((draw.seed, episode))
        played = {
            i: (draw.seed, episode)
            for (i, draw), episode in zip(now, recorded[: len(now)], strict=True)
        }
        episodes: list[RecordedEpisode | EpisodeDraw] = []
        for i in envs.tolist():
            seed, episode = played[i] if i in played else self._queues[i].popleft()
            self._episode_seeds[i] = seed
            episodes.append(episode)
        engine.begin(envs, episodes)

    def _draw(self, i: int, explicit: dict[int, int]) -> EpisodeDraw:
        """Sub-env ``i``'s next episode: the explicit seed's, the seed source's next, or its own
        generator's (seeded for its first episode, continued after)."""
        if i in explicit or self._sources is not None:
            seed = explicit[i] if i in explicit else int(self._sources[i].next())  # type: ignore[index]
            return EpisodeDraw(seed, seeding.np_random(seed)[0])
        seed, rng = self._generator_seeds[i], self._rngs[i]
        assert rng is not None
        self._generator_seeds[i] = None  # its later episodes continue the generator
        return EpisodeDraw(seed, rng)

    def _to_record(self, envs: NDArray[np.intp]) -> list[tuple[int, EpisodeDraw]]:
        """The episodes to record ahead now for a start of the sub-envs ``envs``, (sub-env,
        draw) in each sub-env's playing order: one for every sub-env short of
        ``RECORD_AHEAD`` (its own generator advances through them; without autoreset only
        for ``envs`` that have none: the others' next episodes may never be asked for), or
        with seed sources every queue topped up (see `RECORD_BATCH`)."""
        jobs: list[tuple[int, EpisodeDraw]] = []
        if self._sources is None:
            wanted = set(range(self.num_envs))
            if self.autoreset_mode == AutoresetMode.DISABLED:
                wanted = {i for i in envs.tolist() if not self._queues[i]}
            for i, (queue, rng) in enumerate(zip(self._queues, self._rngs, strict=True)):
                if i in wanted and len(queue) < RECORD_AHEAD and rng is not None:
                    jobs.append((i, EpisodeDraw(self._generator_seeds[i], rng)))
                    self._generator_seeds[i] = None  # its later episodes continue the generator
            return jobs
        depth = max(RECORD_AHEAD, math.ceil(RECORD_BATCH / self.num_envs))
        for i, (queue, source) in enumerate(zip(self._queues, self._sources, strict=True)):
            for _ in range(depth - len(queue)):
                seed = int(source.next())
                jobs.append((i, EpisodeDraw(seed, seeding.np_random(seed)[0])))
        return jobs

    def _step(
        self,
        idx: NDArray[np.intp],
        action: FloatArray,
        rewards: FloatArray,
        terminated: NDArray[np.bool_],
        truncated: NDArray[np.bool_],
    ) -> dict[str, Any]:
        """The engine's step of the sub-envs ``idx`` (their actions), in place; returns the
        vector info."""
        n, engine = self.num_envs, self._live_engine()
        out = engine.step(idx, action)
        terminated[idx], truncated[idx] = out.terminated, out.truncated
        rewards[idx] = out.reward
        values = out.info
        if idx.size == n:  # every sub-env stepped (no autoreset this step)
            info = values
            mask = np.ones(n, dtype=bool)
        else:
            info = {key: _scatter(n, idx, value) for key, value in values.items()}
            mask = self._mask(idx)
        info.update({f"_{key}": mask.copy() for key in values})
        over = idx[out.terminated | out.truncated]
        limit = np.full(n, np.nan)
        for i in over.tolist():
            bound = engine.episodes[i].bound  # type: ignore[union-attr]
            assert bound is not None  # recorded and rendered sides bound every episode
            limit[i] = bound.time
        info["physical_limit_time"] = limit
        info["_physical_limit_time"] = self._mask(over)
        return info

    def _mask(self, envs: NDArray[np.intp]) -> NDArray[np.bool_]:
        """(N,) True at ``envs``."""
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[envs] = True
        return mask

    def _reset_info(self, envs: NDArray[np.intp]) -> dict[str, NDArray]:
        """``CaptureEnv.reset``'s info (time 0 and the distance) for the sub-envs ``envs``."""
        mask = self._mask(envs)
        return {
            "time": np.where(mask, 0.0, np.nan),
            "_time": mask,
            "distance": np.where(mask, self._live_engine().state.distance, np.nan),
            "_distance": mask.copy(),
        }


def sub_env_infos(info: dict[str, Any], n: int) -> list[dict[str, Any]]:
    """The n sub-envs' entries of a gymnasium vector ``info`` (``_key`` masks), as the single
    env gives them: Python scalars, None for the step rule's ``OPTIONAL_KEYS`` where NaN (and for no
    failure). One ``tolist()`` per key: indexing the arrays element by element costs several
    times as much."""
    out: list[dict[str, Any]] = [{} for _ in range(n)]
    for key, values in info.items():
        if key.startswith("_"):
            continue
        optional = key in OPTIONAL_KEYS
        for env_info, marked, value in zip(
            out, info[f"_{key}"].tolist(), values.tolist(), strict=True
        ):
            if marked:
                env_info[key] = None if optional and value != value else value  # NaN: None
    return out


def _scatter(n: int, idx: NDArray[np.intp], value: NDArray) -> NDArray:
    """An (n,) array holding ``value`` at ``idx`` (zero, False, NaN or None elsewhere)."""
    if value.dtype == object:
        out = np.full(n, None, dtype=object)
    elif value.dtype == bool:
        out = np.zeros(n, dtype=bool)
    else:
        out = np.full(n, np.nan)
    out[idx] = value
    return out


def _autoreset_mode(mode: AutoresetMode | str) -> AutoresetMode:
    """``mode`` as one of `AUTORESET_MODES`, or ``ValueError`` naming them."""
    try:
        value = AutoresetMode(mode)
    except ValueError:
        value = None
    if value not in AUTORESET_MODES:
        valid = ", ".join(f"AutoresetMode.{m.name} ({m.value!r})" for m in AUTORESET_MODES)
        raise ValueError(f"autoreset_mode must be one of {valid}; got {mode!r}")
    return value
