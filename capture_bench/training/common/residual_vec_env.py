"""Training a residual on an analytic controller (`capture_bench.agents.residual`): a
``VecEnvWrapper`` whose action is the residual pi(s), stepping the envs with
clip(a_base(s) + alpha pi(s)).

It sits directly on the environments (inside ``VecNormalize``, when there is one), so the base
controller sees the raw observation; the learner sees what it would see without it, and
everything else (rewards, dones, infos, seeds) passes through unchanged. After a same-step reset
the remembered observation is the new episode's first, as the learner's.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvStepReturn, VecEnvWrapper

from capture_bench.agents.residual import combine, make_base
from capture_bench.task.observation import TaskDescription


class ResidualVecEnv(VecEnvWrapper):
    """``venv`` whose actions are residuals on ``base`` scaled by ``scale``.

    Args:
        venv: the training envs (raw observations).
        base: a name of `capture_bench.agents.residual.RESIDUAL_BASES`.
        scale: alpha.
        description: the task's public description (the base controller's only knowledge).
    """

    def __init__(self, venv: VecEnv, base: str, scale: float, description: TaskDescription):
        super().__init__(venv)
        self.base = make_base(base, description)
        self.scale = float(scale)
        self._obs: Any = None

    def reset(self) -> Any:
        self._obs = self.venv.reset()
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        if self._obs is None:
            raise RuntimeError("ResidualVecEnv.step_async() called before reset()")
        base, _ = self.base.predict(self._obs)
        self.venv.step_async(combine(base, actions, self.scale))

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        self._obs = obs
        return obs, rewards, dones, infos
