"""``CaptureSB3VecEnv``: Stable-Baselines3's ``VecEnv`` contract over the batched
[`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv].

SB3 cannot take a gymnasium ``VectorEnv``; this adapter gives it the batched env with SB3's
semantics, those of ``DummyVecEnv`` over ``TrainingSeeds(CaptureEnv(..., reuse_target_side=True))``
single envs (``tests/test_sb3_vec_env.py`` checks every transition equal):

* same-step reset: when sub-env i's episode ends, row i of the returned observations is the new
  episode's first observation, ``infos[i]["terminal_observation"]`` the final one, and
  ``infos[i]["TimeLimit.truncated"]`` is ``truncated and not terminated``; ``dones`` is
  ``terminated | truncated``; rewards are float32 (as ``DummyVecEnv``'s buffer);
* ``infos`` is a list of per-env dicts with the single env's keys and Python values (None where
  ``CaptureEnv`` gives None), the new episode's reset ``info`` in ``reset_infos[i]``;
* every episode's seed is drawn from the scenario's training seeds by a
  `TrainingSeedDraw` per sub-env, seeded
  ``seed * 1000 + i`` as ``train.py``'s ``make_env`` seeds rank i; `seed` (SB3 calls it
  with the model's seed) re-seeds draw i with ``seed + i`` at the next `reset`, exactly as
  ``DummyVecEnv`` passes ``seed + i`` to ``TrainingSeeds.reset``. No evaluation or validation
  seed is ever used.

How it stays fast with every episode seeded: the draws are the batched env's seed sources
(`CaptureVectorEnv.set_episode_seeds`), so the batched env draws each sub-env's next seeds
as it records their episodes ahead, many at once; a re-seed hands it the re-seeded draws again,
which discards what was recorded from the old ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from capture_bench.envs.vector_env import CaptureVectorEnv, sub_env_infos
from capture_bench.task.scenarios import Scenario
from capture_bench.training.seeds import TrainingSeedDraw


class CaptureSB3VecEnv(VecEnv):
    """N capture episodes stepped together, as an SB3 ``VecEnv`` (see the module docstring).

    Args:
        n_envs: number of sub-envs N.
        scenario: a shipped name, a YAML path or a ``Scenario``.
        seed: seeds the episode draws: sub-env i's with ``seed * 1000 + i``.
        observation_source: ``"ekf"``, ``"photogrammetry"`` or ``"truth"`` (default: the
            scenario's), or ``"pixels"``.
        reward: ``"dense"`` or ``"sparse"``.
        image_size: with ``"pixels"``, the image's (width, height), pixels (None: the env's
            default).
        critic_state: with ``"pixels"``, each observation also holds ``critic_state``, the
            true observation of the step (privileged; training only: the asymmetric critic,
            `capture_bench.training.common.asymmetric`).
        pixel_options: with ``"pixels"``, ``frame_stack``, ``ee_crop``, ``ee_crop_scale``,
            ``image_supersample``, ``ee_crop_supersample`` (``CaptureEnv``'s keys).

    Observations: float32, (N, *single observation shape), or with pixels a dict of such arrays
    (``image`` uint8 (N, 3, H, W), ``state`` float32 (N, 7)), each row of which is replaced
    on a same-step reset; actions: (N, 3) in [-1, 1] (as ``CaptureEnv``).
    ``get_attr``/``set_attr``/``env_method`` reach the batched env's attributes, the same for
    every sub-env, plus ``episode_seed`` (per sub-env, as ``TrainingSeeds``'s);
    ``env_is_wrapped`` is False (no gymnasium wrapper inside).
    """

    def __init__(
        self,
        n_envs: int,
        scenario: str | Path | Scenario = "paper",
        *,
        seed: int = 0,
        observation_source: str | None = None,
        reward: str = "dense",
        image_size: tuple[int, int] | None = None,
        critic_state: bool = False,
        **pixel_options: int | None,
    ) -> None:
        self.venv = CaptureVectorEnv(
            n_envs,
            scenario,
            observation_source=observation_source,
            reward=reward,
            image_size=image_size,
            **pixel_options,
        )
        self._draws = [TrainingSeedDraw(self.venv.scenario, seed * 1000 + i) for i in range(n_envs)]
        self.venv.set_episode_seeds(self._draws)
        self._actions: NDArray | None = None
        self.critic_state = bool(critic_state)
        space = self.venv.single_observation_space
        if self.critic_state:
            from capture_bench.training.common.asymmetric import critic_space

            if not isinstance(space, gym.spaces.Dict):
                raise ValueError("critic_state is added to the pixel observation only")
            space = critic_space(space)
        super().__init__(n_envs, space, self.venv.single_action_space)

    # -- SB3 VecEnv API -------------------------------------------------------------------------
    def reset(self) -> Batch:
        """Reset every sub-env on its next training seed; the observations, (N, ...)."""
        if any(self._options):
            raise ValueError(f"CaptureSB3VecEnv.reset takes no options, got {self._options!r}")
        if any(seed is not None for seed in self._seeds):
            for draw, seed in zip(self._draws, self._seeds, strict=True):
                if seed is not None:
                    draw.reseed(seed)
            self.venv.set_episode_seeds(self._draws)  # discards what the old draws recorded
        obs, info = self._with_truth(self.venv.reset())
        self.reset_infos = sub_env_infos(info, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return _copy(obs)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("CaptureSB3VecEnv.step_wait() called without step_async()")
        actions, self._actions = self._actions, None
        # Finished sub-envs are reset below, so the batched env's own next-step autoreset
        # never fires: every sub-env steps.
        obs, rewards, terminated, truncated, info = self.venv.step(actions)
        obs = self._with_truth((obs, None))[0]
        dones = terminated | truncated
        infos = sub_env_infos(info, self.num_envs)
        for env_info, limit in zip(infos, (truncated & ~terminated).tolist(), strict=True):
            env_info["TimeLimit.truncated"] = limit
        if dones.any():
            ended = np.flatnonzero(dones)
            for i in ended.tolist():
                infos[i]["terminal_observation"] = _row(obs, i)
            new_obs, reset_info = self._with_truth(self.venv.reset(options={"reset_mask": dones}))
            obs = _replace_rows(obs, new_obs, dones)
            new_infos = sub_env_infos(reset_info, self.num_envs)
            for i in ended.tolist():
                self.reset_infos[i] = new_infos[i]
        return _copy(obs), rewards.astype(np.float32), dones, infos

    def _with_truth(self, result: tuple[Batch, Any]) -> tuple[Batch, Any]:
        """``(obs, info)`` with ``critic_state`` (the true observation, privileged) added to the
        observation where the env was made with ``critic_state``."""
        obs, info = result
        if self.critic_state:
            from capture_bench.training.common.asymmetric import CRITIC_KEY

            obs = {**obs, CRITIC_KEY: self.venv.true_observation()}
        return obs, info

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Re-seed draw i with ``seed + i`` at the next `reset` (SB3's rule; a random
        ``seed`` when None)."""
        return super().seed(seed)

    def close(self) -> None:
        """Close the batched env (its pybullet world); safe twice."""
        self.venv.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The attribute for each sub-env in ``indices``: ``episode_seed`` per sub-env, any
        other the batched env's (one value shared by all, e.g. ``render_mode`` None)."""
        targets = list(self._get_indices(indices))
        if attr_name == "episode_seed":
            return [self.episode_seeds[i] for i in targets]
        value = getattr(self.venv, attr_name)
        return [value for _ in targets]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute of the batched env; only for every sub-env at once (they share
        it)."""
        if sorted(self._get_indices(indices)) != list(range(self.num_envs)):
            raise ValueError(
                f"CaptureSB3VecEnv.set_attr({attr_name!r}) sets the batched env's attribute, "
                "shared by every sub-env: pass indices=None"
            )
        setattr(self.venv, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs
    ) -> list[Any]:
        """Call a method of the batched env once; its result, repeated for each sub-env in
        ``indices``."""
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        """False for every sub-env: the batched env holds no gymnasium wrapper (SB3 asks
        whether a ``Monitor`` is inside; wrap this VecEnv in ``VecMonitor`` instead)."""
        return [False for _ in self._get_indices(indices)]

    @property
    def episode_seeds(self) -> list[int | None]:
        """The training seed of each sub-env's current episode (None before `reset`)."""
        return self.venv.episode_seeds


Batch = NDArray | dict[str, NDArray]  # (N, ...) observations, or a dict of them (pixels)


def _copy(obs: Batch) -> Batch:
    if isinstance(obs, dict):
        return {key: value.copy() for key, value in obs.items()}
    return obs.copy()


def _row(obs: Batch, i: int) -> Any:
    """Sub-env i's observation, copied (a dict of rows with pixels)."""
    if isinstance(obs, dict):
        return {key: value[i].copy() for key, value in obs.items()}
    return obs[i].copy()


def _replace_rows(obs: Batch, new: Batch, rows: NDArray[np.bool_]) -> Batch:
    """``obs`` with the rows in ``rows`` taken from ``new``."""
    if isinstance(obs, dict) and isinstance(new, dict):
        return {key: _rows_replaced(value, new[key], rows) for key, value in obs.items()}
    assert not isinstance(obs, dict) and not isinstance(new, dict)
    return _rows_replaced(obs, new, rows)


def _rows_replaced(obs: NDArray, new: NDArray, rows: NDArray[np.bool_]) -> NDArray:
    mask = rows.reshape(-1, *([1] * (obs.ndim - 1)))
    return np.where(mask, new, obs)
