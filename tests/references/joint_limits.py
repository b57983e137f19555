"""The arm's rate and joint limits for one arm, a joint at a time in Python floats: the reference
that `capture_bench.sim.world.limit_joint_increments` must equal bit for bit."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from capture_bench.sim.kinematics import ArmSpec
from capture_bench.sim.world import SATURATION_FRACTION


class JointStep(NamedTuple):
    """What one step of the limits did: the angles after it, rad, (3,); whether a limit reduced
    the request; whether some joint ran at its rate limit; whether some joint ends on a limit."""

    theta: np.ndarray
    clipped: bool
    saturated: bool
    at_joint_limit: bool


def apply_joint_increment(theta, delta_theta, dt: float, arm: ArmSpec | None = None) -> JointStep:
    """One arm at ``theta`` (3,) asked for ``delta_theta`` (3,) over ``dt`` s: each ``|delta_i|``
    clipped to ``theta_dot_max_i * dt``, then the result to the joint limits (a joint already
    outside them may not move further out)."""
    arm = ArmSpec() if arm is None else arm
    dt = float(dt)
    new = []
    clipped = saturated = at_limit = False
    for d_i, q_i, rate, lower, upper in zip(
        (float(v) for v in delta_theta),
        (float(v) for v in theta),
        arm.joint_rate_limits.tolist(),
        arm.joint_lower.tolist(),
        arm.joint_upper.tolist(),
    ):
        step_max = rate * dt
        step = step_max if d_i > step_max else (-step_max if d_i < -step_max else d_i)
        unclipped = q_i + step
        q = min(max(unclipped, min(lower, q_i)), max(upper, q_i))
        clipped = clipped or step != d_i or q != unclipped
        saturated = saturated or abs(q - q_i) >= SATURATION_FRACTION * step_max
        at_limit = at_limit or q <= lower or q >= upper
        new.append(q)
    return JointStep(np.array(new), clipped, saturated, at_limit)
