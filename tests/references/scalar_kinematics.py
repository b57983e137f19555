"""Inverse kinematics and reachability one point at a time in Python floats, written out
separately from `capture_bench.sim.kinematics.inverse_kinematics` and `reachable`: the references
they must equal (solutions as sets, to rounding; reachability exactly). Angles are wrapped to
(-pi, pi] here, so a solution on the wrap (an angle of pi) appears as pi here and as -pi there."""

from __future__ import annotations

import math

import numpy as np

from capture_bench.sim.kinematics import JOINT_LOWER, JOINT_UPPER, L1, L2


def inverse_kinematics(position) -> np.ndarray:
    """Every closed-form solution of f(Theta) = X for one point (global, m, (3,)), rad, (K, 3)
    with K in {0, 2, 4} (0 out of reach), distinct rows in lexicographic order, no joint limits.

    Joint 1 faces the point (r > 0) or faces away (r < 0), each with two elbow solutions.
    """
    x, y, z = np.asarray(position, dtype=float)
    rho = float(np.hypot(x, y))
    base = float(np.arctan2(y, x))
    solutions = []
    for sign_r, t1 in ((1.0, base), (-1.0, base + np.pi)):
        r = sign_r * rho
        # r = (l1 + l2 s3) c2 + l2 c3 s2, z = (l1 + l2 s3) s2 - l2 c3 c2
        s3 = (r * r + z * z - L1 * L1 - L2 * L2) / (2.0 * L1 * L2)
        if abs(s3) > 1.0 + 1e-12:
            continue
        s3 = float(np.clip(s3, -1.0, 1.0))
        c3_abs = float(np.sqrt(1.0 - s3 * s3))
        for c3 in (c3_abs, -c3_abs):
            t3 = np.arctan2(s3, c3)
            a, b = L1 + L2 * s3, L2 * c3
            t2 = np.arctan2(a * z + b * r, a * r - b * z)
            solutions.append([_wrap(t1), _wrap(t2), _wrap(t3)])
    if not solutions:
        return np.zeros((0, 3))
    return np.unique(np.round(np.array(solutions), 15), axis=0)


def _wrap(angle: float) -> float:
    """An angle wrapped to (-pi, pi]."""
    wrapped = (angle + np.pi) % (2.0 * np.pi) - np.pi
    return float(np.pi if wrapped == -np.pi else wrapped)


def reachable(position) -> bool:
    """Whether one point (global, m, (3,)) has an IK solution inside the published joint limits,
    in ``math``: joint 1 facing the point (r > 0), both elbows."""
    x, y, z = (float(c) for c in position)
    lo, hi = JOINT_LOWER.tolist(), JOINT_UPPER.tolist()
    t1 = math.atan2(y, x)
    if not lo[0] <= t1 <= hi[0]:
        return False
    r = math.hypot(x, y)
    s3 = (r * r + z * z - L1 * L1 - L2 * L2) / (2.0 * L1 * L2)
    if abs(s3) > 1.0:
        return False
    c3_abs = math.sqrt(1.0 - s3 * s3)
    for c3 in (c3_abs, -c3_abs):
        a, b = L1 + L2 * s3, L2 * c3
        t2 = math.atan2(a * z + b * r, a * r - b * z)
        t3 = math.atan2(s3, c3)
        if lo[1] <= t2 <= hi[1] and lo[2] <= t3 <= hi[2]:
            return True
    return False
