"""Acquisition: what an analytic controller does while it has never had an estimate.

With the rendered camera the arm at home can hide markers from the first frame: the filter cannot
start, and a controller that waits for an estimate waits for ever (``target_lost``). A scenario
whose camera the arm can hide publishes an acquisition yaw (`TaskDescription.acquisition_yaw`:
the joint-1 angle at which the arm points along the camera's horizontal line of sight, away from
the camera, so that it shows the camera its smallest profile). Then, once ``ACQUIRE_AFTER``
observations of an episode in a row have had no estimate and none before them did, `Acquisition`
replaces the controller's action by a swing of joint 1 toward that yaw at up to its rate limit,
joints 2 and 3 held, until the first estimate; from there on the controller acts as it would.

The first observation of a rendered episode has no estimate yet, and the filter starts on the
next frame when enough markers are seen, so ``ACQUIRE_AFTER = 2`` leaves every episode whose
filter starts on its first step as it was. A loss of the estimate later in the episode (a
diverged filter) is not acquisition: the controller holds as before. Without an acquisition yaw
(the analytic camera, which the arm never hides) nothing changes.

It needs to know where each episode starts: ``predict``'s ``episode_start`` (as SB3 and the
evaluation pass it) or ``reset``. `AnalyticController.act` and ``act_batch`` stay functions of the
observation alone, without acquisition.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from capture_bench.task.observation import (
    OBSERVATION_SIZE,
    TaskDescription,
    decode_observation,
    estimate_seen,
)

#: Consecutive observations without an estimate, from an episode's start, before acquisition.
ACQUIRE_AFTER = 2


class Acquisition:
    """Per-row acquisition state of a controller's batch (see the module docstring).

    Args:
        description: the task's description; its ``acquisition_yaw`` must not be None.
    """

    def __init__(self, description: TaskDescription) -> None:
        if description.acquisition_yaw is None:
            raise ValueError("Acquisition needs a TaskDescription with an acquisition_yaw")
        self.description = description
        self.yaw = float(description.acquisition_yaw)
        self.blind = np.zeros(0, dtype=np.int64)  # observations without an estimate, per row
        self.tracking = np.zeros(0, dtype=bool)  # whether the row has had an estimate

    def reset(self) -> None:
        """Every row starts a new episode."""
        self.blind = np.zeros(0, dtype=np.int64)
        self.tracking = np.zeros(0, dtype=bool)

    def apply(
        self, observation: NDArray, action: NDArray, episode_start: NDArray | None = None
    ) -> NDArray[np.float32]:
        """The action with the rows that acquire replaced by the swing toward the yaw.

        Args:
            observation: (16,) or (N, 16), the observations ``action`` answers.
            action: (3,) or (N, 3), the controller's actions for them.
            episode_start: (N,) whether each row starts an episode with this observation.

        Returns:
            Actions of ``action``'s shape, float32.
        """
        rows = np.asarray(observation).reshape(-1, OBSERVATION_SIZE)
        n = rows.shape[0]
        if self.blind.shape[0] != n:
            self.blind = np.zeros(n, dtype=np.int64)
            self.tracking = np.zeros(n, dtype=bool)
        if episode_start is not None:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            self.blind[starts] = 0
            self.tracking[starts] = False
        if self.tracking.all():  # every row has had its estimate: nothing left to acquire
            return np.asarray(action, dtype=np.float32)
        obs = decode_observation(rows, self.description.control_period)
        seen = estimate_seen(obs)
        self.tracking |= seen
        self.blind = np.where(self.tracking, 0, self.blind + 1)
        acquire = self.blind >= ACQUIRE_AFTER
        if not acquire.any():
            return np.asarray(action, dtype=np.float32)
        out = np.array(action, dtype=np.float32).reshape(n, 3)
        out[acquire] = self.swing(obs.joint_angles[acquire])
        return out.reshape(np.shape(action))

    def swing(self, joint_angles: NDArray) -> NDArray[np.float32]:
        """Actions (M, 3) that turn joint 1 toward the yaw at up to its rate, joints 2, 3 held."""
        arm = self.description.arm
        full_step = arm.joint_rate_limits[0] * self.description.control_period
        actions = np.zeros((joint_angles.shape[0], 3), dtype=np.float32)
        actions[:, 0] = np.clip((self.yaw - joint_angles[:, 0]) / full_step, -1.0, 1.0)
        return actions
