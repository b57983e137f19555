"""A stand-in environment with the benchmark's spaces, and small SB3 models trained on it (fast:
no pybullet), for tests of model files and checkpoints."""

from __future__ import annotations

import numpy as np


def spaces():
    import gymnasium

    observation = gymnasium.spaces.Box(-10, 10, (16,), np.float32)
    action = gymnasium.spaces.Box(-1, 1, (3,), np.float32)
    return observation, action


def sb3_model(algorithm: str, normalize: bool = False, learn: int = 0):
    """A small SB3 model on a stand-in env with the benchmark's spaces (trained ``learn`` steps,
    so its weights are not the initial ones), and its VecNormalize (or None)."""
    import gymnasium
    import stable_baselines3
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    observation_space, action_space = spaces()

    class Stand(gymnasium.Env):
        def __init__(self):
            self.observation_space, self.action_space = observation_space, action_space

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            return self.observation_space.sample(), {}

        def step(self, action):
            obs = self.observation_space.sample()
            return obs, float(-np.abs(action).sum()), False, False, {}

    venv = DummyVecEnv([Stand])
    venv = VecNormalize(venv) if normalize else venv
    kwargs: dict = {"policy_kwargs": {"net_arch": [16, 16]}, "seed": 0, "device": "cpu"}
    if algorithm in ("PPO", "A2C"):
        kwargs["n_steps"] = 32
        if algorithm == "PPO":
            kwargs |= {"batch_size": 32, "n_epochs": 1}
            kwargs["policy_kwargs"] |= {"activation_fn": __import__("torch").nn.ReLU}
    else:
        kwargs |= {"learning_starts": 16, "batch_size": 16, "buffer_size": 1000}
    model = getattr(stable_baselines3, algorithm)("MlpPolicy", venv, **kwargs)
    if learn:
        model.learn(learn)
    return model, (venv if normalize else None)


#: The smallest PPO run train.py takes (64 steps, one env, a 16-unit network), as a --config file.
TINY_PPO = """\
n_envs: 1
total_timesteps: 64
policy_kwargs: {net_arch: [16]}
n_steps: 32
batch_size: 32
n_epochs: 1
checkpoint_freq: 32
"""
