"""Reward terms of ``CaptureEnv`` (each one is also reported in ``info``)."""

from __future__ import annotations

REWARD_MODES = ("dense", "sparse")
PROGRESS_GAIN = 10.0  # reward per metre of true distance closed
TIME_PENALTY = -0.01  # per step
CAPTURE_BONUS = 5.0
FAILURE_PENALTY = -5.0  # collision, target_lost, unreachable (not timeout)


def reward_terms(
    mode: str, previous_distance: float, distance: float, captured: bool, failure: str | None
) -> dict[str, float]:
    """The reward of one step, split into named terms.

    Args:
        mode: ``"dense"`` or ``"sparse"``.
        previous_distance: true ||X_E - X_T|| before the step, m.
        distance: the same after the step, m.
        captured: eq. 20 held during the step.
        failure: the step's failure reason or None.
    """
    if mode == "sparse":
        return {"reward_capture": 1.0 if captured else 0.0}
    return {
        "reward_progress": PROGRESS_GAIN * (previous_distance - distance),
        "reward_time": TIME_PENALTY,
        "reward_capture": CAPTURE_BONUS if captured else 0.0,
        "reward_failure": FAILURE_PENALTY if failure not in (None, "timeout") else 0.0,
    }
