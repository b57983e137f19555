"""The reward terms of a capture step, over N episodes at once (one definition for both envs).

``reward="dense"``: progress on the true distance ||X_E - X_T|| (eq. 20's quantity), a time
penalty per step, a bonus on capture (eq. 20 held during the step) and a penalty on every failure
but ``timeout``. ``reward="sparse"``: 1 on capture. Each term is also reported in ``info`` under
its name; :data:`REWARD_TERMS` names them per mode, in the order they are summed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

PROGRESS_GAIN = 10.0  # reward per metre of true distance closed
TIME_PENALTY = -0.01  # per step
CAPTURE_BONUS = 5.0
FAILURE_PENALTY = -5.0  # collision, target_lost, unreachable (not timeout)
UNPENALISED_FAILURES = ("timeout",)  # failures that do not earn FAILURE_PENALTY

#: The terms of each reward mode, in the order they are summed.
REWARD_TERMS: dict[str, tuple[str, ...]] = {
    "dense": ("reward_progress", "reward_time", "reward_capture", "reward_failure"),
    "sparse": ("reward_capture",),
}
REWARD_MODES = tuple(REWARD_TERMS)


def reward_terms(
    mode: str,
    previous_distance: NDArray[np.float64],
    distance: NDArray[np.float64],
    captured: NDArray[np.bool_],
    penalised: NDArray[np.bool_],
) -> dict[str, NDArray[np.float64]]:
    """The reward of one step of M episodes, split into the named terms of ``mode``.

    Args:
        mode: ``"dense"`` or ``"sparse"``.
        previous_distance: true ||X_E - X_T|| before the step, m, (M,).
        distance: the same after the step, m, (M,).
        captured: eq. 20 held during the step, (M,).
        penalised: the step ended with a failure other than :data:`UNPENALISED_FAILURES`, (M,).

    Returns:
        ``{term: (M,) values}`` with the keys of ``REWARD_TERMS[mode]``, in that order.
    """
    if mode == "sparse":
        return {"reward_capture": np.where(captured, 1.0, 0.0)}
    return {
        "reward_progress": PROGRESS_GAIN * (previous_distance - distance),
        "reward_time": np.full(distance.shape, TIME_PENALTY),
        "reward_capture": np.where(captured, CAPTURE_BONUS, 0.0),
        "reward_failure": np.where(penalised, FAILURE_PENALTY, 0.0),
    }


def total_reward(terms: dict[str, NDArray[np.float64]]) -> NDArray[np.float64]:
    """The step's reward: the terms summed in their order, (M,)."""
    total = np.zeros(next(iter(terms.values())).shape)
    for value in terms.values():
        total = total + value
    return total
