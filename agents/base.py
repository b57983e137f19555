"""What the analytic controllers share: decoding, SB3-style ``predict``, ``reset``, a safe action.

An :class:`AnalyticController` subclass implements :meth:`~AnalyticController.act` (one
observation, shape (16,), to one action, shape (3,)); ``predict`` applies it to one observation or
a batch (:func:`predict_each`), the shape of SB3's ``PolicyPredictor`` (:mod:`agents.protocol`).
:func:`safe_action` is the last step of every controller: clip to [-1, 1] and never emit NaN.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.task.observation import Observation, TaskDescription, decode_observation


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

    Subclasses implement :meth:`act` (one observation -> one action). Built from the environment's
    public :class:`TaskDescription` only, never from the world.
    """

    privileged = False

    def __init__(self, description: TaskDescription) -> None:
        self.description = description

    def decode(self, observation: NDArray) -> Observation:
        """Observation (16,) -> SI units (see ``capture_bench/task/observation.py``)."""
        return decode_observation(observation, self.description.control_period)

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """Action for one observation, shape (3,), float32, in [-1, 1]."""
        raise NotImplementedError

    def predict(
        self,
        observation: NDArray,
        state: Any = None,
        episode_start: NDArray | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[np.float32], Any]:
        """SB3-style predict, observation (16,) or (N, 16): ``(action, state)``, state unchanged."""
        return predict_each(self.act, observation), state

    def reset(self) -> None:
        """Start of an episode; the analytic controllers keep no episode state."""
