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

    Batches (optional): an agent whose ``batched`` attribute is true also takes N observations,
    shape (N, 16), and returns actions of shape (N, 3), each row as it would be alone (no row's
    action depends on another row, nor on N), keeping any episode state per row; ``reset`` then
    starts N episodes. The analytic controllers of `capture_bench.agents.baselines` and
    `capture_bench.agents.incremental_ik` are batched. The evaluation builds a batched
    agent once per batch of episodes and asks it with every episode's observation at each step
    (row i for episode i; an ended episode's action is ignored); any other agent once per
    episode, each asked with its own episode's observation
    (`capture_bench.evaluation.running.rollout.run_episodes`).
    """

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]: ...

    def reset(self) -> None: ...
