"""What the analytic controllers share: decoding, SB3-style ``predict``, ``reset``, a safe action.

An [`AnalyticController`][capture_bench.agents.base.AnalyticController] subclass implements
[`act_batch`][capture_bench.agents.base.AnalyticController.act_batch] (N
observations, shape (N, 16), to N actions, shape (N, 3), each row computed as it would be alone)
and gets [`act`][capture_bench.agents.base.AnalyticController.act] (one observation) and ``predict``
(one or a batch) from
it (``batched`` is then True). A subclass that implements only
[`act`][capture_bench.agents.base.AnalyticController.act]
still works: ``predict`` applies it row by row (`predict_each`), and ``batched`` is False.
`safe_action` is the last step of every controller: clip to [-1, 1] and never emit NaN.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.agents.acquisition import Acquisition
from capture_bench.task.observation import (
    OBSERVATION_SIZE,
    Observation,
    TaskDescription,
    decode_observation,
)


def predict_each(
    act: Callable[[NDArray], NDArray[np.float32]], observation: NDArray
) -> NDArray[np.float32]:
    """Apply a single-observation policy to shape (16,) or a batch (N, 16)."""
    obs = np.asarray(observation)
    if obs.ndim == 2:
        return np.stack([act(o) for o in obs]).astype(np.float32)
    return act(obs)


def safe_action(action: NDArray) -> NDArray[np.float32]:
    """Clip to [-1, 1]^3 as float32; any non-finite entry becomes 0 (hold that joint)."""
    a = np.asarray(action, dtype=float)
    a = np.where(np.isfinite(a), a, 0.0)
    return np.minimum(np.maximum(a, -1.0), 1.0).astype(np.float32)


class AnalyticController:
    """Shared plumbing of the analytic controllers: decode, SB3-style ``predict``, ``reset``.

    Subclasses implement [`act_batch`][capture_bench.agents.base.AnalyticController.act_batch] (N
    observations -> N actions, vectorised, no row
    depending on another) or, for a controller written for one observation,
    [`act`][capture_bench.agents.base.AnalyticController.act]. Built
    from the environment's public `TaskDescription` only, never from the world.
    """

    privileged = False
    #: Whether ``predict`` acquires (`capture_bench.agents.acquisition`) where the task has an
    #: acquisition yaw; the baselines that do not track (hold, random) do not.
    acquires = True

    def __init__(self, description: TaskDescription) -> None:
        self.description = description
        use = self.acquires and description.acquisition_yaw is not None
        self.acquisition = Acquisition(description) if use else None

    @property
    def batched(self) -> bool:
        """Whether ``predict`` handles a batch in one vectorised computation with per-row
        results (the subclass implements
        [`act_batch`][capture_bench.agents.base.AnalyticController.act_batch])."""
        return type(self).act_batch is not AnalyticController.act_batch

    def decode(self, observation: NDArray) -> Observation:
        """Observation (16,) or (N, 16) -> SI units (see ``capture_bench/task/observation.py``)."""
        return decode_observation(observation, self.description.control_period)

    def act_batch(self, observations: NDArray) -> NDArray[np.float32]:
        """Actions for N observations (N, 16) -> (N, 3), float32, in [-1, 1]; by default
        [`act`][capture_bench.agents.base.AnalyticController.act] row by row."""
        return predict_each(self.act, np.asarray(observations).reshape(-1, OBSERVATION_SIZE))

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """Action for one observation (16,) -> (3,), float32, in [-1, 1]:
        [`act_batch`][capture_bench.agents.base.AnalyticController.act_batch]'s
        row."""
        if not self.batched:
            raise NotImplementedError(f"{type(self).__name__} implements neither act nor act_batch")
        return self.act_batch(np.asarray(observation)[None])[0]

    def predict(
        self,
        observation: NDArray,
        state: Any = None,
        episode_start: NDArray | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[np.float32], Any]:
        """SB3-style predict, observation (16,) or (N, 16): ``(action, state)``, state unchanged;
        with acquisition (the task's ``acquisition_yaw``) the rows that have never had an
        estimate swing joint 1 clear of the camera's line of sight instead."""
        obs = np.asarray(observation)
        action = self.act_batch(obs) if obs.ndim == 2 else self.act(obs)
        if self.acquisition is not None:
            action = self.acquisition.apply(obs, action, episode_start)
        return action, state

    def reset(self) -> None:
        """Start of an episode (of every row of a batch): only acquisition keeps episode state
        here; subclasses that keep their own call this too."""
        if self.acquisition is not None:
            self.acquisition.reset()
