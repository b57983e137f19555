"""Training a policy behind a front end (``front_end: marker_pose``,
`capture_bench.agents.marker_pose`): a ``VecEnvWrapper`` whose observation is the front end's
vector of each sub-env's pixel observation.

The front end keeps state per sub-env (the target's last pose), so the wrapper steps it once a
step, in order, and restarts a sub-env's at its episode's end: the observation after a done is
the new episode's first (SB3's auto-reset), and the ended episode's last observation
(``terminal_observation`` in its info, which PPO bootstraps a truncated episode from) is read
with the ended episode's state first. Rewards, dones and the rest of the infos pass through; the
wrapped env's other methods (``env_method``: the estimate the teacher reads) are its own.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvStepReturn, VecEnvWrapper

from capture_bench.agents.marker_pose import MarkerCalibration, MarkerPoseTracker, front_end_space


class FrontEndVecEnv(VecEnvWrapper):
    """``venv`` (pixel observations) seen through a `MarkerPoseTracker` of ``stack`` steps with
    ``calibration``."""

    def __init__(self, venv: VecEnv, calibration: MarkerCalibration, stack: int) -> None:
        super().__init__(venv, observation_space=front_end_space(stack))
        self.tracker = MarkerPoseTracker(calibration, venv.num_envs, stack)

    def reset(self) -> Any:
        self.tracker.restart()
        return self.tracker(self.venv.reset())

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        ended = np.flatnonzero(dones)
        for i in ended:
            last = infos[i].get("terminal_observation")
            if last is not None:
                single = {k: np.asarray(v)[None] for k, v in last.items()}
                infos[i]["terminal_observation"] = self.tracker(single, [i])[0]
        self.tracker.restart(ended)
        return self.tracker(obs), rewards, dones, infos
