"""A hybrid agent: a learned residual on top of an analytic controller,

    a = clip(a_base(s) + alpha * pi(s), -1, 1),

the direction that asks whether learning can improve the paper's controller rather than replace
it. ``train.py`` trains pi this way with ``residual: incremental_ik`` (and ``residual_scale``
alpha; `capture_bench.training.common.residual_vec_env.ResidualVecEnv` applies the sum inside the
training envs), the model's metadata declares ``residual: {base, scale}``, and evaluation rebuilds
the same sum (`residual_agent`). The leaderboard labels such a row a hybrid: it is not a
learned controller on its own.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.agents.base import safe_action
from capture_bench.task.observation import OBSERVATION_SIZE, TaskDescription

#: The analytic controllers a residual may sit on: deterministic, acting from the observation
#: alone (built from the task's public description).
RESIDUAL_BASES = (
    "incremental_ik",
    "incremental_ik_uncapped",
    "incremental_ik_through",
    "pure_pursuit",
    "intercept",
    "joint_intercept",
    "joint_intercept_uncapped",
    "dls",
    "joint_intercept_dls",
)
#: The analytic controllers an imitation may learn from (``imitate``): the residual bases, and
#: ``planned_intercept``, which keeps each row's plan between calls, so that it labels a row's
#: observations only as that row's episodes come, in order (as a run's training envs give them).
TEACHERS = (*RESIDUAL_BASES, "planned_intercept")


def make_base(
    name: str, description: TaskDescription, allowed: tuple[str, ...] = RESIDUAL_BASES
) -> Any:
    """The analytic controller ``name`` of ``allowed`` (`RESIDUAL_BASES`, or `TEACHERS`), built
    from ``description``."""
    from capture_bench.agents import make_agent

    if name not in allowed:
        raise ValueError(f"analytic controller {name!r}; valid: {', '.join(allowed)}")
    return make_agent(name, SimpleNamespace(unwrapped=SimpleNamespace(description=description)))


def combine(base_action: NDArray, residual: NDArray, scale: float) -> NDArray[np.float32]:
    """clip(a_base + scale * residual) to the action space, row by row for a batch."""
    total = np.asarray(base_action, dtype=float) + scale * np.asarray(residual, dtype=float)
    return safe_action(total)


class ResidualAgent:
    """``base`` plus ``scale`` times ``learned``'s action (module docstring), as an
    [`capture_bench.agents.protocol.Agent`][capture_bench.agents.protocol.Agent].

    Args:
        base: an analytic controller (``predict`` on one observation or a batch).
        learned: anything with SB3's ``predict`` (an SB3 model,
            `capture_bench.agents.sb3_policy.SB3Policy`); it sees the observation the base
            sees.
        scale: alpha.
        name: label for reports.
    """

    privileged = False

    def __init__(self, base: Any, learned: Any, scale: float, name: str = "residual") -> None:
        self.base, self.learned, self.scale, self.name = base, learned, float(scale), name

    def predict(
        self,
        observation: NDArray,
        state: Any = None,
        episode_start: NDArray | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[np.float32], Any]:
        """SB3-style predict, one observation (16,) or a batch (N, 16)."""
        base, _ = self.base.predict(observation, episode_start=episode_start)
        residual, state = self.learned.predict(
            observation, state=state, episode_start=episode_start, deterministic=deterministic
        )
        return combine(base, residual, self.scale), state

    def predict_rows(self, observations: NDArray) -> NDArray[np.float32]:
        """The deterministic action of each of N observations, (N, 16) -> (N, 3), each row
        what ``predict`` gives that observation alone (without acquisition): the base's batch
        (its rows are computed as alone) plus the learned part's ``predict_rows``."""
        base = self.base.act_batch(np.asarray(observations).reshape(-1, OBSERVATION_SIZE))
        return combine(base, self.learned.predict_rows(observations), self.scale)

    def reset(self) -> None:
        """Start of an episode for both parts."""
        self.base.reset()
        if hasattr(self.learned, "reset"):
            self.learned.reset()
