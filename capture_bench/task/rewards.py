"""The reward terms of a capture step, over N episodes at once (one definition, both envs).

``reward="dense"``: progress on the true distance ||X_E - X_T|| (eq. 20's quantity), a time
penalty per step, a charge for arriving fast, a bonus on capture (eq. 20 held during the step)
and a penalty on every failure but ``timeout``. ``reward="sparse"``: 1 on capture.
``reward="shaped"``: dense with its progress term replaced by potential-based shaping (Ng,
Harada & Russell 1999),

    F = gamma * Phi(d') - Phi(d),   Phi(d) = -SHAPING_SCALE * ln(1 + d / SHAPING_LENGTH),

on the true distance d before and d' after the step: a logarithmic potential, so that closing
the last millimetre (d from 2 mm to 1 mm: F ~ 0.41) is worth about as much as closing the first
10 cm (0.3 m to 0.2 m: F ~ 0.46), where dense's linear progress gives 0.01 against 1.0. Shaping
of this form leaves the optimal policy unchanged (for ``gamma`` equal to the training discount,
`SHAPING_GAMMA`); over an episode its discounted sum telescopes to
gamma**T * Phi(d_T) - Phi(d_0) (``tests/test_rewards.py``). Each term is also reported in
``info`` under its name; `REWARD_TERMS` names them per mode, in the order they are summed.

The speed term (dense and shaped) pays for a capture a gripper could make rather than a pass
through the capture point at speed, a collision:

    reward_speed = -SPEED_GAIN * max(0, v - v_ref) * exp(-c / SPEED_LENGTH),

with v the end-effector's instantaneous speed relative to the capture point at the step's end,
``|J(theta) dtheta/dt - Xdot_T|`` (m/s; within a step the joint rates are constant, so this is
also the speed at which the step passed the target, to the Jacobian's turn), ``v_ref`` the
scenario's ``capture.v_max``, and c the closest approach of X_E - X_T during the step (m, on the
straight segment between the step's ends): a fly-through is charged for the step that passes
the target, wherever its end lands, the capturing step included. A scenario without a speed
bound (``capture.v_max: null``, the paper's eq. 20) captures at any speed, and the term is 0
there: the reward trains for the scenario's rule. It is not shaping: it changes which policies
are optimal, on purpose (arriving slow pays more than flying through). The weight is taken as 0
(it is below 2.1e-9) where a step stays beyond `SPEED_REACH`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

PROGRESS_GAIN = 10.0  # reward per metre of true distance closed
TIME_PENALTY = -0.01  # per step
CAPTURE_BONUS = 5.0
FAILURE_PENALTY = -5.0  # collision, target_lost, unreachable (not timeout)
UNPENALISED_FAILURES = ("timeout",)  # failures that do not earn FAILURE_PENALTY

SHAPING_GAMMA = 0.99  # the discount the shaping assumes: train with gamma = SHAPING_GAMMA
SHAPING_SCALE = 1.0  # Phi's scale
SHAPING_LENGTH = 1e-3  # m, where Phi turns from linear to logarithmic: eq. 20's 1 mm tolerance

SPEED_GAIN = 1.0  # reward per m/s of relative speed above v_ref, per step, at the target
SPEED_LENGTH = 0.01  # m: the speed term's weight exp(-c / SPEED_LENGTH) falls by e per 10 mm
SPEED_REACH = 20.0 * SPEED_LENGTH  # m: beyond it the weight (< 2.1e-9) is taken as 0

#: The terms of each reward mode, in the order they are summed.
REWARD_TERMS: dict[str, tuple[str, ...]] = {
    "dense": ("reward_progress", "reward_time", "reward_speed", "reward_capture", "reward_failure"),
    "sparse": ("reward_capture",),
    "shaped": ("reward_shaping", "reward_time", "reward_speed", "reward_capture", "reward_failure"),
}
REWARD_MODES = tuple(REWARD_TERMS)


#: (M,) arrays for M episodes
Values = Any


def reward_terms(
    mode: str,
    previous_distance: Values,
    distance: Values,
    captured: Values,
    penalised: Values,
    *,
    relative_speed: Values = 0.0,
    closest: Values = np.inf,
    speed_limit: float = math.inf,
) -> dict[str, Values]:
    """The reward of one step of M episodes (arrays (M,)), split into the named terms of
    ``mode``.

    Args:
        mode: one of `REWARD_MODES`.
        previous_distance: true ||X_E - X_T|| before the step, m.
        distance: the same after the step, m.
        captured: eq. 20 held during the step.
        penalised: the step ended with a failure other than `UNPENALISED_FAILURES`.
        relative_speed: the end-effector's instantaneous speed relative to the capture point at
            the step's end, m/s.
        closest: the closest approach of X_E - X_T during the step, m (inf: far).
        speed_limit: v_ref, the scenario's ``capture.v_max``, m/s (default inf: no bound, and
            no speed term).

    Returns:
        ``{term: values}`` with the keys of ``REWARD_TERMS[mode]``, in that order.
    """
    if mode == "sparse":
        return {"reward_capture": _where_flagged(captured, 1.0)}
    if mode == "shaped":
        first = {
            "reward_shaping": SHAPING_GAMMA * potential(distance) - potential(previous_distance)
        }
    else:
        first = {"reward_progress": PROGRESS_GAIN * (previous_distance - distance)}
    return {
        **first,
        "reward_time": TIME_PENALTY + 0.0 * distance,
        "reward_speed": (
            0.0 * distance  # no speed bound: no charge
            if speed_limit == math.inf
            else speed_penalty(relative_speed, closest, speed_limit) + 0.0 * distance
        ),
        "reward_capture": _where_flagged(captured, CAPTURE_BONUS),
        "reward_failure": _where_flagged(penalised, FAILURE_PENALTY),
    }


def _where_flagged(flags: Values, value: float) -> Values:
    """``value`` where ``flags`` (bool, (M,)), 0.0 elsewhere: ``np.where(flags, value, 0.0)``'s
    floats in two calls that together cost less than it at one row, where numpy's per-call
    overhead is the cost."""
    out = np.zeros(flags.shape)
    out[flags] = value
    return out


def speed_penalty(relative_speed: Values, closest: Values, speed_limit: float) -> Values:
    """-SPEED_GAIN * max(0, v - v_ref) * exp(-c / SPEED_LENGTH): the speed term of a relative
    speed v (m/s) at a closest approach c (m), v_ref = ``speed_limit`` (m/s); 0 where v <= v_ref
    (always with v_ref inf) or c is inf."""
    excess = np.maximum(relative_speed - speed_limit, 0.0)
    return -SPEED_GAIN * excess * np.exp(closest * (-1.0 / SPEED_LENGTH))


def potential(distance: Values) -> Values:
    """Phi(d) = -SHAPING_SCALE * ln(1 + d / SHAPING_LENGTH): the shaping potential of a true
    distance d, m (arrays or a float; 0 at d = 0, decreasing)."""
    return -SHAPING_SCALE * np.log1p(distance * (1.0 / SHAPING_LENGTH))


def total_reward(terms: dict[str, Values]) -> Values:
    """The step's reward: the terms summed in their order."""
    total: Any = 0.0
    for value in terms.values():
        total = total + value
    return total
