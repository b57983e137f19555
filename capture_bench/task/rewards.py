"""The reward terms of a capture step, over N episodes at once or one (one definition, both envs).

``reward="dense"``: progress on the true distance ||X_E - X_T|| (eq. 20's quantity), a time
penalty per step, a bonus on capture (eq. 20 held during the step) and a penalty on every failure
but ``timeout``. ``reward="sparse"``: 1 on capture. Each term is also reported in ``info`` under
its name; :data:`REWARD_TERMS` names them per mode, in the order they are summed.
"""

from __future__ import annotations

from typing import Any

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


#: (M,) arrays for M episodes, or one episode's Python float / bool
Values = Any


def reward_terms(
    mode: str, previous_distance: Values, distance: Values, captured: Values, penalised: Values
) -> dict[str, Values]:
    """The reward of one step of M episodes (arrays (M,)) or of one (scalars), split into the
    named terms of ``mode``.

    Args:
        mode: ``"dense"`` or ``"sparse"``.
        previous_distance: true ||X_E - X_T|| before the step, m.
        distance: the same after the step, m.
        captured: eq. 20 held during the step.
        penalised: the step ended with a failure other than :data:`UNPENALISED_FAILURES`.

    Returns:
        ``{term: values}`` with the keys of ``REWARD_TERMS[mode]``, in that order.
    """
    # Arithmetic only (a bool times a number, + 0.0 so that no term is -0.0), so that the same
    # lines serve numpy arrays (M,) and the single env's Python floats and bools.
    if mode == "sparse":
        return {"reward_capture": 1.0 * captured + 0.0}
    return {
        "reward_progress": PROGRESS_GAIN * (previous_distance - distance),
        "reward_time": TIME_PENALTY + 0.0 * distance,
        "reward_capture": CAPTURE_BONUS * captured + 0.0,
        "reward_failure": FAILURE_PENALTY * penalised + 0.0,
    }


def total_reward(terms: dict[str, Values]) -> Values:
    """The step's reward: the terms summed in their order."""
    total: Any = 0.0
    for value in terms.values():
        total = total + value
    return total
