"""The one protocol every agent follows, analytic controller or trained policy.

It has the shape of Stable-Baselines3's ``PolicyPredictor`` (``predict``) plus ``reset``, so SB3
models and the analytic controllers run through one evaluation path.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Agent(Protocol):
    """An agent maps observations to actions in the shared action space ``Box(-1, 1, (3,))``.

    ``predict`` takes one observation, shape (16,) (see ``capture_bench/task/observation.py``), and
    returns ``(action, state)`` with ``action`` of shape (3,), float32, inside [-1, 1]; ``state``
    is a recurrent state (``None`` for stateless agents). ``reset`` is called at the start of
    every episode.
    """

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]: ...

    def reset(self) -> None: ...
