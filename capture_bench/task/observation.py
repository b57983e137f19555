"""The observation vector and the task's public description.

Everything here is what an agent may know: the observation layout and its scales, the arm's
published constants, the nominal control period and the capture tolerance. None of it is the
world's ground truth.

Observation layout (float32, shape (16,), every entry divided by its scale so it is of order one):

=====  ===============================================  ========  ===========
index  quantity (global frame)                          unit      scale
=====  ===============================================  ========  ===========
0-2    estimated target (capture point) position X^_T   m         1 m
3-5    estimated target velocity Xdot^_T                m/s       0.1 m/s
6-8    end-effector position X_E                        m         1 m
9-11   joint angles Theta                               rad       pi rad
12-14  predicted relative vector X^_T' - X_E (eq. 13)   m         0.5 m
15     last real control period dt                      s         t_s
=====  ===============================================  ========  ===========

The pixel observation (``observation_source="pixels"``) is a ``Dict`` instead
(`pixel_observation_space`): ``image``, the camera's uint8 image, channel-first
(`capture_bench.sensing.workspace_image`; with a frame stack the last k images along the
channels, oldest first), ``ee_image`` where the end-effector crop is asked for, and ``state``,
what the agent knows without vision (`encode_state`, float32, shape (7,), scaled as above):

=====  ===============================================  ========  ===========
index  quantity (global frame)                          unit      scale
=====  ===============================================  ========  ===========
0-2    joint angles Theta                               rad       pi rad
3-5    end-effector position X_E                        m         1 m
6      last real control period dt                      s         t_s
=====  ===============================================  ========  ===========
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from capture_bench.sim.kinematics import ArmSpec

OBSERVATION_SIZE = 16
OBSERVATION_BOUND = 10.0  # every scaled entry is clipped to [-10, 10]
POSITION_SCALE = 1.0  # m
VELOCITY_SCALE = 0.1  # m/s
ANGLE_SCALE = np.pi  # rad
RELATIVE_SCALE = 0.5  # m

# every entry's 1 / scale, in the layout's order (the period's scale, t_s, is divided first)
_INVERSE_SCALES = 1.0 / np.repeat(
    [POSITION_SCALE, VELOCITY_SCALE, POSITION_SCALE, ANGLE_SCALE, RELATIVE_SCALE, 1.0],
    [3, 3, 3, 3, 3, 1],
)

SLICES = {
    "target_position": slice(0, 3),
    "target_velocity": slice(3, 6),
    "ee_position": slice(6, 9),
    "joint_angles": slice(9, 12),
    "relative_position": slice(12, 15),
    "last_period": slice(15, 16),
}


@dataclass(frozen=True)
class TaskDescription:
    """What an environment publishes about itself for agents.

    Attributes:
        arm: the arm's constants (link lengths, joint rate and position limits, home).
        control_period: nominal control period t_s, s.
        capture_tolerance: epsilon of eq. 20, m, shape (3,).
        acquisition_yaw: where the camera can be hidden by the arm, the joint-1 angle that
            points the arm along the camera's horizontal line of sight, away from it, rad
            (`capture_bench.agents.acquisition`); None where the arm never hides the camera.
    """

    arm: ArmSpec = field(default_factory=ArmSpec)
    control_period: float = 0.05
    capture_tolerance: NDArray[np.float64] = field(default_factory=lambda: np.full(3, 1e-3))
    acquisition_yaw: float | None = None

    def action_to_increment(self, action: NDArray) -> NDArray[np.float64]:
        """Joint increment requested by an action: dTheta = a * theta_dot_max * t_s, rad, (3,)."""
        return np.asarray(action, dtype=float) * self.arm.joint_rate_limits * self.control_period

    def increment_to_action(self, increment: NDArray) -> NDArray[np.float32]:
        """Action that requests a joint increment (inverse of
        [`action_to_increment`][capture_bench.task.observation.TaskDescription.action_to_increment]),
        clipped to the action space [-1, 1]^3."""
        action = np.asarray(increment, dtype=float) / (
            self.arm.joint_rate_limits * self.control_period
        )
        return np.clip(action, -1.0, 1.0).astype(np.float32)


@dataclass(frozen=True)
class Observation:
    """A decoded observation, in SI units and the global frame (see module docstring)."""

    target_position: NDArray[np.float64]
    target_velocity: NDArray[np.float64]
    ee_position: NDArray[np.float64]
    joint_angles: NDArray[np.float64]
    relative_position: NDArray[np.float64]
    last_period: Any  # s: a float, or shape (N,) for a batch


def estimate_seen(obs: Observation) -> NDArray[np.bool_]:
    """Whether each decoded observation (a batch) carries an estimate: without one the target
    entries repeat the end-effector position with zero velocity."""
    same = np.all(obs.target_position == obs.ee_position, axis=-1)
    return ~(same & np.all(obs.target_velocity == 0.0, axis=-1))


def observation_space() -> spaces.Box:
    """The observation space: Box(-10, 10, (16,), float32)."""
    return spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, (OBSERVATION_SIZE,), np.float32)


STATE_SIZE = 7  # the pixel observation's ``state``: Theta (3), X_E (3), dt (1)
_STATE_INVERSE_SCALES = 1.0 / np.repeat([ANGLE_SCALE, POSITION_SCALE, 1.0], [3, 3, 1])


def pixel_observation_space(
    image_size: tuple[int, int], frame_stack: int = 1, ee_crop: int = 0
) -> spaces.Dict:
    """The pixel observation's space for an image of ``image_size`` (width, height), pixels:
    ``Dict(image=Box(0, 255, (3 k, height, width), uint8), state=Box(-10, 10, (7,), float32))``
    with k = ``frame_stack`` images stacked along the channels, oldest first; with ``ee_crop``
    n > 0 also ``ee_image=Box(0, 255, (3 k, n, n), uint8)``, the end-effector crop
    (`capture_bench.sensing.workspace_image`)."""
    width, height = image_size
    channels = 3 * frame_stack
    images = {"image": spaces.Box(0, 255, (channels, height, width), np.uint8)}
    if ee_crop:
        images["ee_image"] = spaces.Box(0, 255, (channels, ee_crop, ee_crop), np.uint8)
    state = spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, (STATE_SIZE,), np.float32)
    return spaces.Dict({**images, "state": state})


def encode_state(
    joint_angles: ArrayLike,
    ee_position: ArrayLike,
    last_period: ArrayLike,
    control_period: float,
) -> NDArray[np.float32]:
    """The pixel observation's ``state`` (module docstring): Theta / pi, X_E / 1 m and
    dt / t_s, clipped to [-10, 10]. Shapes: (3,), (3,) and a float -> (7,); (M, 3), (M, 3) and
    (M,) -> (M, 7)."""
    period = np.asarray(last_period, dtype=float) / control_period
    raw = np.concatenate(
        (np.asarray(joint_angles, float), np.asarray(ee_position, float), period[..., None]), -1
    )
    state = raw * _STATE_INVERSE_SCALES
    np.clip(state, -OBSERVATION_BOUND, OBSERVATION_BOUND, out=state)
    return state.astype(np.float32)


def encode_observation(
    target_position: ArrayLike,
    target_velocity: ArrayLike,
    ee_position: ArrayLike,
    joint_angles: ArrayLike,
    last_period: ArrayLike,
    control_period: float,
) -> NDArray[np.float32]:
    """The scaled observation (see the module docstring) of one step or of M at once.

    Args:
        target_position, target_velocity: the estimate X^_T (m) and its rate (m/s), global.
        ee_position: X_E, global, m.
        joint_angles: Theta, rad.
        last_period: the last real control period dt, s.
        control_period: the nominal t_s, s (eq. 13's look-ahead and the period's scale).

    Shapes: (3,) vectors and a float -> (16,), or (M, 3) and (M,) -> (M, 16). The relative
    vector is eq. 13 with t_s; every entry is clipped to [-10, 10].
    """
    position = np.asarray(target_position, dtype=float)
    velocity = np.asarray(target_velocity, dtype=float)
    ee = np.asarray(ee_position, dtype=float)
    relative = position + velocity * control_period - ee  # eq. 13, relative to X_E
    period = np.asarray(last_period, dtype=float) / control_period
    raw = np.concatenate((position, velocity, ee, joint_angles, relative, period[..., None]), -1)
    obs = raw * _INVERSE_SCALES
    np.minimum(obs, OBSERVATION_BOUND, out=obs)
    np.maximum(obs, -OBSERVATION_BOUND, out=obs)
    return obs.astype(np.float32)


def decode_observation(obs: NDArray, control_period: float) -> Observation:
    """Undo the scaling of `encode_observation`: shape (16,) -> SI units, or a batch
    (N, 16) -> fields with leading axis N (``last_period`` then shape (N,))."""
    o = np.asarray(obs, dtype=np.float64)
    if o.ndim not in (1, 2) or o.shape[-1] != OBSERVATION_SIZE:
        raise ValueError(
            f"observation must have shape ({OBSERVATION_SIZE},) or (N, {OBSERVATION_SIZE}), "
            f"got {o.shape}"
        )
    last_period = o[..., 15] * control_period
    return Observation(
        target_position=o[..., 0:3] * POSITION_SCALE,
        target_velocity=o[..., 3:6] * VELOCITY_SCALE,
        ee_position=o[..., 6:9] * POSITION_SCALE,
        joint_angles=o[..., 9:12] * ANGLE_SCALE,
        relative_position=o[..., 12:15] * RELATIVE_SCALE,
        last_period=float(last_period) if o.ndim == 1 else last_period,
    )
