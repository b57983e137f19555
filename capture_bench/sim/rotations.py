"""Rotation helpers shared by the target motion, the camera and the estimator.

Euler convention (the EKF's and photogrammetry's angles):
``R = Rz(theta_z) @ Ry(theta_y) @ Rx(theta_x)``, angles in radians. All matrices map frame-local
coordinates to the parent frame (columns are the local axes expressed in the parent).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray


def euler_to_matrix(angles: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix Rz @ Ry @ Rx from (theta_x, theta_y, theta_z), rad; shape (3, 3)."""
    ax, ay, az = np.asarray(angles, dtype=float)
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    return np.array(
        [
            [cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
            [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
            [-sy, cy * sx, cy * cx],
        ]
    )


def matrix_to_euler(rotation: ArrayLike) -> NDArray[np.float64]:
    """Inverse of `euler_to_matrix`: (theta_x, theta_y, theta_z), rad.

    theta_y is in [-pi/2, pi/2].
    """
    r = np.asarray(rotation, dtype=float)
    theta_y = np.arcsin(np.clip(-r[2, 0], -1.0, 1.0))
    theta_x = np.arctan2(r[2, 1], r[2, 2])
    theta_z = np.arctan2(r[1, 0], r[0, 0])
    return np.array([theta_x, theta_y, theta_z])


def axis_angle_to_matrix(axis: ArrayLike, angle: float) -> NDArray[np.float64]:
    """Rodrigues' formula: rotation by ``angle`` rad about unit ``axis`` (3,); shape (3, 3)."""
    k = np.asarray(axis, dtype=float)
    k = k / np.linalg.norm(k)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * (kx @ kx)


def look_at(
    position: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)
) -> NDArray[np.float64]:
    """Camera rotation R_gc whose y-axis points from ``position`` toward ``target`` (global, m).

    The camera z-axis is as close to ``up`` as possible; x completes a right-handed frame.
    """
    y = np.asarray(target, dtype=float) - np.asarray(position, dtype=float)
    y = y / np.linalg.norm(y)
    x = np.cross(y, np.asarray(up, dtype=float))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("camera looks straight along 'up'; choose another up vector")
    x = x / np.linalg.norm(x)
    z = np.cross(x, y)
    return np.column_stack([x, y, z])


def quaternion_xyzw(r: Sequence[Sequence[float]]) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a rotation matrix given as nested lists (Shepperd)."""
    m00, m01, m02 = r[0]
    m10, m11, m12 = r[1]
    m20, m21, m22 = r[2]
    trace = m00 + m11 + m22
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        return ((m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, 0.25 * s)
    if m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        return (0.25 * s, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s)
    if m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        return ((m01 + m10) / s, 0.25 * s, (m12 + m21) / s, (m02 - m20) / s)
    s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
    return ((m02 + m20) / s, (m12 + m21) / s, 0.25 * s, (m10 - m01) / s)
