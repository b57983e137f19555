"""The reinforcement-learning algorithms ``train.py`` trains, by the name ``--algo`` and
``configs/algos/<algo>.yaml`` give them. A model's metadata names its algorithm in SB3's spelling
(``PPO``: `capture_bench.agents.policy_file.POLICY_CLASSES`)."""

from __future__ import annotations

#: SB3's PPO, A2C, SAC, TD3 and DDPG, and TQC from sb3-contrib.
ALGORITHMS = ("ppo", "a2c", "sac", "td3", "ddpg", "tqc")
