"""A conservative geometric screen for the arm's collisions, so batched envs ask pybullet rarely.

`clear_of_collisions` bounds the collision shapes of `World`
(floor, base column, self-contact) from the joint angles alone, with ``CLEARANCE`` to spare: True
means "certainly no collision", False means "ask pybullet". Tested against pybullet on random
poses (``tests/test_vector_env.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from capture_bench.sim.kinematics import L0, L1, L2, FloatArray

# Bounds of the collision model (see World): everything on the forearm and wrist lies within
# FOREARM_REACH of the segment elbow -> end-effector (tube offset 0.06 m + radius 0.025 m; the
# bracket ends 0.06 m + 0.02 m from the tip), the upper arm within 0.025 m of joint 2 -> elbow.
FOREARM_REACH = 0.085  # m
UPPER_ARM_RADIUS = 0.025  # m
COLUMN_RADIUS = 0.05  # m; the column spans z in [-L0, 0]
SELF_CONTACT_THETA3 = math.radians(-80.0)  # the wrist meets the upper arm only below ~-84 deg
CLEARANCE = 0.01  # m: what "clearly" means in clear_of_collisions


def clear_of_collisions(theta: FloatArray) -> NDArray[np.bool_]:
    """For M joint vectors (M, 3), rad: True where the arm is certainly in no collision of
    `World.collision`, by bounds on its collision shapes with ``CLEARANCE`` to spare.

    False means "ask pybullet": a batched env queries its worlds only there.
    """
    t2, t3 = theta[:, 1], theta[:, 2]
    # Joint 2 at the origin, the elbow and the tip in the arm's vertical plane: (r, z), where r is
    # the horizontal distance along the arm's heading (the tube's sideways offset only adds to
    # the horizontal distance from the column's axis, so |r| bounds it from below).
    elbow_r, elbow_z = L1 * np.cos(t2), L1 * np.sin(t2)
    tip_r, tip_z = elbow_r + L2 * np.sin(t2 + t3), elbow_z - L2 * np.cos(t2 + t3)
    forearm_low = np.minimum(elbow_z, tip_z) - FOREARM_REACH
    upper_arm_low = np.minimum(elbow_z, 0.0) - UPPER_ARM_RADIUS
    above_floor = np.minimum(forearm_low, upper_arm_low) > -L0 + CLEARANCE
    crosses_axis = elbow_r * tip_r <= 0.0
    min_r = np.where(crosses_axis, 0.0, np.minimum(np.abs(elbow_r), np.abs(tip_r)))
    beside_column = min_r - FOREARM_REACH > COLUMN_RADIUS + CLEARANCE
    above_column = forearm_low > CLEARANCE
    unfolded = t3 > SELF_CONTACT_THETA3
    return above_floor & (above_column | beside_column) & unfolded
