"""A minimal agent of your own, evaluated like any built-in one:

    python evaluate.py --agents examples.my_agent:MyAgent --scenarios paper --episodes 20

`MyAgent` is a resolved-rate controller: it asks for the end-effector velocity that follows the
estimated target (feed-forward of its velocity) and closes a share of the remaining gap each
control period, turns it into joint rates through the arm's Jacobian, and scales them down
together to the joint-rate limits. Slowing as the gap closes is what lets it land on the target
at the target's own speed, as the capture envelope asks.

It sees what every agent sees: one observation (16 numbers: the estimated target position and
velocity, the end-effector, the joint angles, the last control period) and the task's public
description (the arm's constants, the control period, the capture tolerance).
"""

from __future__ import annotations

import numpy as np

from capture_bench.sim.kinematics import forward_kinematics, jacobian
from capture_bench.task.observation import TaskDescription, decode_observation


class MyAgent:
    """Follow the estimate's velocity and close ``share`` of the gap to it every period."""

    def __init__(self, description: TaskDescription, share: float = 0.4) -> None:
        self.description = description
        self.gain = share / description.control_period  # 1/s

    def reset(self) -> None:
        """A new episode: this agent keeps no state between steps."""

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """One observation, shape (16,) -> (action in [-1, 1], shape (3,); the state, None)."""
        obs = decode_observation(observation, self.description.control_period)  # SI units
        theta = obs.joint_angles
        gap = obs.target_position - forward_kinematics(theta)  # m
        wanted = obs.target_velocity + self.gain * gap  # end-effector velocity, m/s
        rate = np.linalg.lstsq(jacobian(theta), wanted, rcond=None)[0]  # joint rates, rad/s
        over = np.max(np.abs(rate) / self.description.arm.joint_rate_limits)
        rate = rate / max(over, 1.0)  # within the limits, its direction kept
        increment = rate * self.description.control_period  # rad
        return np.clip(self.description.increment_to_action(increment), -1.0, 1.0), state
