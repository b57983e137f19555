"""``CaptureVectorEnv``: N capture episodes stepped together with stacked numpy.

``gymnasium.make_vec("CaptureBench/Paper-v0", num_envs=64)`` builds one (the registered
``vector_entry_point``). Sub-env i behaves as ``CaptureEnv(scenario, reuse_target_side=True)``
seeded like gymnasium's ``SyncVectorEnv`` seeds its i-th env, with next-step autoreset: the same
episodes, the same observations, rewards and ``info`` (tests compare them, to rounding: the batched
arithmetic may differ from the single env's in the last bits).

How it is fast: nothing on the target's side of a step depends on the actions, so each sub-env's
next episodes are recorded ahead, many at once
(:func:`capture_bench.task.recording.record_episodes`: camera vectorised over time, EKF and bound
over episodes), and a step only does the arm's side: the joint limits, forward kinematics, the
capture test over the step, failures, reward and observation for all sub-envs together, and a
pybullet collision query only for the sub-envs whose arm is near the floor or the base column
(:func:`capture_bench.sim.collision_screen.clear_of_collisions`).

Differences from N single envs, all in the format only:

* ``info`` is gymnasium's vector form: each key holds an (N,) array and ``_key`` marks the sub-envs
  that report it. ``capture_time``, ``capture_time_estimated`` and ``physical_limit_time`` are NaN
  where the single env gives None (``physical_limit_time`` is marked only where an episode ended);
  ``failure`` and ``estimator_status`` are object arrays of the single env's values. A sub-env
  that autoresets reports its reset ``info`` (``time``, ``distance``) that step.
* No rendering, and no privileged API (oracle agents use the single env).
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from capture_bench.envs.capture_env import FAILURES, CaptureEnv, check_actions
from capture_bench.sensing.camera import Camera
from capture_bench.sensing.estimator import STATUSES
from capture_bench.sim import kinematics
from capture_bench.sim.collision_screen import clear_of_collisions
from capture_bench.sim.world import World, limit_joint_increments
from capture_bench.task.capture import (
    ARC_RESOLUTION,
    arc_sag_bounds,
    closest_approaches,
    first_entry_along_arc,
    first_entry_fractions,
)
from capture_bench.task.episode import TIME_SLACK, period_count, time_limit
from capture_bench.task.observation import encode_observations
from capture_bench.task.recording import RecordedEpisode, record_episodes
from capture_bench.task.rewards import (
    CAPTURE_BONUS,
    FAILURE_PENALTY,
    PROGRESS_GAIN,
    TIME_PENALTY,
)
from capture_bench.task.scenarios import Scenario

FloatArray = NDArray[np.float64]
RECORD_AHEAD = 2  # episodes recorded ahead per sub-env (batches of ~num_envs episodes)
_STATUS_OK = STATUSES.index("ok")
_STATUS_NAMES = np.array(STATUSES, dtype=object)
_FAILURE_NAMES = np.array((None, *FAILURES), dtype=object)  # code 0: no failure
_COLLISION, _UNREACHABLE, _TARGET_LOST, _TIMEOUT = (
    1 + FAILURES.index(name) for name in ("collision", "unreachable", "target_lost", "timeout")
)
# Per-step quantities of the recorded episodes, stacked (N, steps, ...) for fancy indexing.
_TRACKS = (
    "time",
    "dt",
    "position",
    "velocity",
    "estimate_position",
    "estimate_velocity",
    "estimate_valid",
    "estimator_status",
    "visible",
    "reachable",
    "position_error",
    "velocity_error",
    "nees",
)


class CaptureVectorEnv(VectorEnv):
    """N :class:`~capture_bench.envs.capture_env.CaptureEnv` episodes of one scenario, stepped
    together.

    Args:
        num_envs: number of sub-envs N.
        scenario: a shipped name, a YAML path or a ``Scenario`` (as ``CaptureEnv``).
        observation_source: ``"ekf"``, ``"photogrammetry"`` or ``"truth"`` (default: the
            scenario's). ``"photogrammetry"`` runs its estimator episode by episode (slower).
        reward: ``"dense"`` or ``"sparse"``.
        reuse_target_side: must be True (accepted so that ``make_vec(id, n,
            reuse_target_side=True)`` means the same for every vectorization mode).
        render_mode: must be None (the vector env does not render).

    Spaces, rewards, termination and ``info`` are ``CaptureEnv``'s (see its docstring), batched;
    see the module docstring for the format of ``info``. Autoreset: next step
    (``metadata["autoreset_mode"]``): the step after a sub-env's episode ends resets it and
    returns its first observation, reward 0 and no termination.
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
        # One single env holds the scenario, the task description, the camera and the spaces (and
        # checks the scenario, source and reward).
        self._single = CaptureEnv(scenario, observation_source=observation_source, reward=reward)
        self.scenario = self._single.scenario
        self.description = self._single.description
        self.reward_mode = reward
        self.render_mode = None
        self.num_envs = n = int(num_envs)
        self.single_observation_space = self._single.observation_space
        self.single_action_space = self._single.action_space
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._features = self._single._features
        self._camera: Camera = self._single._camera
        # One pybullet world answers every sub-env's collision query in turn (a world per
        # sub-env would cost ~28 MB each): the joints are set before each query.
        self._world: World | None = World(self._features)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._queues: list[deque[RecordedEpisode]] = [deque() for _ in range(n)]
        # Row i holds sub-env i's episode, step by step (an episode has at most one step more
        # than it has control periods).
        steps = period_count(self.scenario.control) + 1
        self._tracks: dict[str, NDArray] = {
            name: np.zeros((n, steps, *_TRACK_SHAPES[name]), dtype=_TRACK_DTYPES[name])
            for name in _TRACKS
        }
        self._bound = np.full(n, np.nan)
        self._episodes: list[RecordedEpisode | None] = [None] * n
        self._steps = np.zeros(n, dtype=np.int64)
        self._theta = np.tile(self.description.arm.home, (n, 1))
        self._x_e = np.zeros((n, 3))
        self._distance = np.zeros(n)
        self._path_length = np.zeros(n)
        self._since_frame = np.zeros(n)
        self._unreachable_for = np.zeros(n)
        self._capture_time_estimated = np.full(n, np.nan)
        self._ended = np.ones(n, dtype=bool)  # reset these sub-envs at the next step
        self._started = False

    # -- gymnasium API --------------------------------------------------------------------------
    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Reset the sub-envs (``options["reset_mask"]``: only those marked).

        ``seed``: an int s seeds sub-env i with s + i, as ``SyncVectorEnv`` does; a list gives
        one seed (or None) per sub-env. An unseeded sub-env continues its own generator.
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
        fresh = {  # every new generator first, so that a bad seed changes nothing
            i: seeding.np_random(seeds[i])[0]
            for i in np.flatnonzero(mask).tolist()
            if seeds[i] is not None or self._rngs[i] is None
        }
        for i, rng in fresh.items():
            self._rngs[i] = rng
            self._queues[i].clear()  # recorded from the old generator
        envs = np.flatnonzero(mask)
        self._start(envs)
        self._ended[envs] = False
        self._started = True
        return self._observe(), self._reset_info(envs)

    def step(
        self, actions: NDArray
    ) -> tuple[
        NDArray[np.float32], FloatArray, NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]
    ]:
        """Step every sub-env with its row of ``actions``, shape (num_envs, 3), in [-1, 1].

        Out-of-range values are clipped; a wrong shape, a non-numeric dtype or a NaN/infinite
        entry raises ``ValueError`` naming it
        (:func:`capture_bench.envs.capture_env.check_actions`, the rule of :class:`CaptureEnv`),
        and nothing is stepped. After ``close()``: ``RuntimeError``.
        """
        if self._world is None:
            raise RuntimeError("CaptureVectorEnv.step() called after close(); the env is closed")
        if not self._started:
            raise RuntimeError("CaptureVectorEnv.step() called before reset(); call reset() first")
        n = self.num_envs
        a = check_actions(actions, (n, 3), "actions")
        resetting = np.flatnonzero(self._ended)
        stepping = np.flatnonzero(~self._ended)
        if resetting.size:
            self._start(resetting)
        rewards = np.zeros(n)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        info = self._step(stepping, a[stepping], rewards, terminated, truncated)
        obs = self._observe()
        if resetting.size:
            for key, value in self._reset_info(resetting).items():
                if key.startswith("_"):
                    info[key] = info.get(key, np.zeros(n, dtype=bool)) | value
                else:
                    info[key] = np.where(self._mask(resetting), value, info[key])
            self._ended[resetting] = False
        self._ended[stepping] = terminated[stepping] | truncated[stepping]
        return obs, rewards, terminated, truncated, info

    def close_extras(self, **kwargs: Any) -> None:
        if self._world is not None:
            self._world.close()
            self._world = None
        self._single.close()

    # -- episodes -------------------------------------------------------------------------------
    def _start(self, envs: NDArray[np.intp]) -> None:
        """Begin the next recorded episode of each sub-env in ``envs`` (recording a batch for
        every sub-env short of episodes when one of them has none)."""
        if any(not self._queues[i] for i in envs.tolist()):
            short = [
                i
                for i, (queue, rng) in enumerate(zip(self._queues, self._rngs, strict=True))
                if len(queue) < RECORD_AHEAD and rng is not None
            ]
            rngs = [self._rngs[i] for i in short]
            recorded = record_episodes(
                self.scenario,
                self._camera,
                self._features,
                self.description,
                rngs,  # type: ignore[arg-type]  # not None in `short`
            )
            for i, episode in zip(short, recorded, strict=True):
                self._queues[i].append(episode)
        home = self.description.arm.home
        for i in envs.tolist():
            episode = self._queues[i].popleft()
            self._episodes[i] = episode
            self._load_tracks(i, episode)
            self._bound[i] = episode.bound.time
        self._steps[envs] = 0
        self._theta[envs] = home
        self._x_e[envs] = kinematics.forward_kinematics_point(home)
        self._path_length[envs] = self._since_frame[envs] = self._unreachable_for[envs] = 0.0
        self._capture_time_estimated[envs] = np.nan
        x_t = self._tracks["position"][envs, 0]
        self._distance[envs] = np.linalg.norm(self._x_e[envs] - x_t, axis=1)

    def _load_tracks(self, i: int, episode: RecordedEpisode) -> None:
        """Copy an episode's per-step arrays into row i of the stacked tracks."""
        length = episode.time.size
        for name in _TRACKS:
            self._tracks[name][i, :length] = getattr(episode, name)

    # -- one step of the arm's side --------------------------------------------------------------
    def _step(
        self,
        idx: NDArray[np.intp],
        action: FloatArray,
        rewards: FloatArray,
        terminated: NDArray[np.bool_],
        truncated: NDArray[np.bool_],
    ) -> dict[str, Any]:
        """``CaptureEnv.step`` for the sub-envs ``idx`` (their actions), in place."""
        n, m = self.num_envs, idx.size
        tracks, desc, sc = self._tracks, self.description, self.scenario
        k = self._steps[idx] + 1
        self._steps[idx] = k
        dt, time, x_t = tracks["dt"][idx, k], tracks["time"][idx, k], tracks["position"][idx, k]
        x_t0 = tracks["position"][idx, k - 1]
        est_valid, est_pos = tracks["estimate_valid"][idx, k], tracks["estimate_position"][idx, k]
        est0_valid = tracks["estimate_valid"][idx, k - 1]
        est0_pos = tracks["estimate_position"][idx, k - 1]

        # The world: rate and joint limits, then pybullet's joints for the collision query.
        request = np.minimum(np.maximum(action, -1.0), 1.0) * desc.arm.joint_rate_limits
        request = request * desc.control_period  # TaskDescription.action_to_increment
        theta0, x_e0, d_prev = self._theta[idx], self._x_e[idx], self._distance[idx]
        theta, clipped, saturated = limit_joint_increments(theta0, request, dt, desc.arm)
        self._theta[idx] = theta
        x_e = kinematics.forward_kinematics(theta)
        self._x_e[idx] = x_e
        self._path_length[idx] += np.linalg.norm(x_e - x_e0, axis=1)

        # Capture over the whole step (eq. 20 on the true target), as CaptureEnv does.
        applied = theta - theta0
        s = self._capture_fractions(idx, theta0, applied, x_e0 - x_t0, x_e - x_t, time - dt, dt)
        captured = ~np.isnan(s)
        capture_time = time - dt + s * dt
        pending = np.isnan(self._capture_time_estimated[idx]) & est0_valid & est_valid
        if pending.any():
            s_est = first_entry_fractions(
                (x_e0 - est0_pos)[pending], (x_e - est_pos)[pending], desc.capture_tolerance
            )
            rows = idx[pending]
            t_start = (time - dt)[pending]
            found = ~np.isnan(s_est)
            self._capture_time_estimated[rows[found]] = (t_start + s_est * dt[pending])[found]

        failure = self._failures(idx, theta, captured, dt, k)
        ended = captured | (failure != 0)
        timeout = ~ended & (time >= time_limit(sc.control))
        failure[timeout] = _TIMEOUT
        terminated[idx], truncated[idx] = ended, timeout

        distance = np.linalg.norm(x_e - x_t, axis=1)
        self._distance[idx] = distance
        terms = self._reward_terms(d_prev, distance, captured, failure)
        total = np.zeros(m)
        for value in terms.values():
            total = total + value
        rewards[idx] = total

        v_e = (x_e - x_e0) / dt[:, None]
        values: dict[str, NDArray] = {
            "is_success": captured,
            "failure": _FAILURE_NAMES[failure],
            "capture_time": capture_time,
            "capture_time_estimated": self._capture_time_estimated[idx],
            "time": time,
            "dt": dt,
            "distance": distance,
            "relative_speed": np.linalg.norm(v_e - tracks["velocity"][idx, k], axis=1),
            "estimate_position_error": tracks["position_error"][idx, k],
            "estimate_velocity_error": tracks["velocity_error"][idx, k],
            "estimate_nees": tracks["nees"][idx, k],
            "saturated": saturated,
            "clipped": clipped,
            "path_length": self._path_length[idx],
            "target_visible": tracks["visible"][idx, k],
            "estimator_status": _STATUS_NAMES[tracks["estimator_status"][idx, k]],
            **terms,
        }
        if m == n:  # every sub-env stepped (no autoreset this step)
            info = values
            mask = np.ones(n, dtype=bool)
        else:
            info = {key: _scatter(n, idx, value) for key, value in values.items()}
            mask = self._mask(idx)
        info.update({f"_{key}": mask.copy() for key in values})
        over = idx[ended | timeout]
        limit = np.full(n, np.nan)
        limit[over] = self._bound[over]
        info["physical_limit_time"] = limit
        info["_physical_limit_time"] = self._mask(over)
        return info

    def _capture_fractions(
        self,
        idx: NDArray[np.intp],
        theta0: FloatArray,
        applied: FloatArray,
        d0: FloatArray,
        d1: FloatArray,
        t0: FloatArray,
        dt: FloatArray,
    ) -> FloatArray:
        """``CaptureEnv._capture_fraction`` for each stepping sub-env: NaN where no capture."""
        tolerance = self.description.capture_tolerance
        s = first_entry_fractions(d0, d1, tolerance)
        sag = arc_sag_bounds(applied)
        arc = sag > ARC_RESOLUTION
        if arc.any():
            radius = self._single._tolerance_radius
            near = arc & ~(closest_approaches(d0, d1) > radius + sag)
            s[arc & ~near] = np.nan
            for j in np.flatnonzero(near).tolist():  # along the true arc (rare: near the target)
                episode = self._episodes[idx[j]]
                assert episode is not None
                traj, start, step = episode.plan.trajectory, float(t0[j]), float(dt[j])

                def target_at(f: FloatArray, traj=traj, start=start, step=step) -> FloatArray:
                    return traj.position(start + f * step)

                entry = first_entry_along_arc(theta0[j], applied[j], target_at, tolerance)
                s[j] = np.nan if entry is None else entry
        return s

    def _failures(
        self,
        idx: NDArray[np.intp],
        theta: FloatArray,
        captured: NDArray[np.bool_],
        dt: FloatArray,
        k: NDArray[np.int64],
    ) -> NDArray[np.int64]:
        """``CaptureEnv._failure`` for the stepping sub-envs: a code into ``_FAILURE_NAMES``."""
        sc = self.scenario
        failure = np.zeros(idx.size, dtype=np.int64)
        ask = ~captured & ~clear_of_collisions(theta)  # pybullet only where contact is possible
        world = self._world
        assert world is not None  # step() refuses to run after close()
        for j in np.flatnonzero(ask).tolist():
            world.set_joint_positions(theta[j].tolist())
            if world.collision() is not None:
                failure[j] = _COLLISION
        lost_after = sc.lost_after + TIME_SLACK
        reach = self._tracks["reachable"][idx, k]
        unreachable_for = np.where(reach, 0.0, self._unreachable_for[idx] + dt)
        self._unreachable_for[idx] = unreachable_for
        failure[(failure == 0) & ~captured & (unreachable_for > lost_after)] = _UNREACHABLE
        if sc.estimator.source != "truth":
            usable = self._tracks["estimator_status"][idx, k] == _STATUS_OK
            since = np.where(usable, 0.0, self._since_frame[idx] + dt)
            self._since_frame[idx] = since
            failure[(failure == 0) & ~captured & (since > lost_after)] = _TARGET_LOST
        return failure

    def _reward_terms(
        self,
        d_prev: FloatArray,
        distance: FloatArray,
        captured: NDArray[np.bool_],
        failure: NDArray[np.int64],
    ) -> dict[str, FloatArray]:
        """:func:`capture_bench.task.rewards.reward_terms`, batched (same terms, same order)."""
        if self.reward_mode == "sparse":
            return {"reward_capture": np.where(captured, 1.0, 0.0)}
        failed = (failure != 0) & (failure != _TIMEOUT)
        return {
            "reward_progress": PROGRESS_GAIN * (d_prev - distance),
            "reward_time": np.full(d_prev.size, TIME_PENALTY),
            "reward_capture": np.where(captured, CAPTURE_BONUS, 0.0),
            "reward_failure": np.where(failed, FAILURE_PENALTY, 0.0),
        }

    def _observe(self) -> NDArray[np.float32]:
        """``CaptureEnv._observation`` of every sub-env at its current step (the last real
        period: that of the step just taken, t_s at reset)."""
        rows, k, tracks = np.arange(self.num_envs), self._steps, self._tracks
        valid = tracks["estimate_valid"][rows, k][:, None]
        position = np.where(valid, tracks["estimate_position"][rows, k], self._x_e)
        velocity = np.where(valid, tracks["estimate_velocity"][rows, k], 0.0)
        return encode_observations(
            position,
            velocity,
            self._x_e,
            self._theta,
            tracks["dt"][rows, k],
            self.scenario.control.period,
        )

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
            "distance": np.where(mask, self._distance, np.nan),
            "_distance": mask.copy(),
        }


_TRACK_SHAPES: dict[str, tuple[int, ...]] = {
    name: (3,) if name in {"position", "velocity", "estimate_position", "estimate_velocity"} else ()
    for name in _TRACKS
}
_TRACK_DTYPES: dict[str, Any] = {
    **dict.fromkeys(_TRACKS, np.float64),
    **dict.fromkeys(("estimate_valid", "visible", "reachable"), np.bool_),
    "estimator_status": np.int8,
}


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
