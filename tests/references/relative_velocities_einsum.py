"""The end-effector's velocity relative to the capture point as the matrix product with eq. 9's
Jacobian: the reference `capture_bench.task.capture.relative_velocities` (its entries multiplied
out) must equal to rounding."""

from __future__ import annotations

import numpy as np

from capture_bench.sim.kinematics import jacobian


def relative_velocities(theta, joint_rates, target_velocity) -> np.ndarray:
    """``J(theta) theta_dot - Xdot_T``, m/s, (K, 3), of joint angles ``theta`` (rad), joint rates
    (rad/s) and the target's velocity Xdot_T (global, m/s), (K, 3) each."""
    return np.einsum("kij,kj->ki", jacobian(theta), joint_rates) - target_velocity
