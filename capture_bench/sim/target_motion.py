"""True motion of the non-cooperative target (never seen by agents).

A trajectory is a translation of the target's centre of rotation ``c(t)`` composed with a rotation
``R(t) = Rot(axis, rate * t) @ R0`` about that centre. The target frame's origin is the capture
point, offset ``r`` (target frame) from the centre, so

    X_T(t) = c(t) + R(t) r,        Xdot_T(t) = cdot(t) + omega x (R(t) r)        (DESIGN.md)

with ``omega = rate * axis`` in the global frame. Every method takes a time in seconds (float or
array of shape (N,)) and returns global-frame quantities in metres, m/s, or rotation matrices.

Translations:

* ``LinearDrift`` — constant velocity.
* ``CircularPath`` — uniform motion on a circle.
* ``Evasive`` — piecewise-constant acceleration that changes direction at given times ("jinks").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sim.rotations import axis_angle_to_matrix

FloatArray = NDArray[np.float64]
_EYE3 = np.eye(3)
#: The most acceleration changes an evasive trajectory may schedule over its horizon (the episode
#: limit over the shortest ``jink_interval``); scenario validation refuses more.
MAX_JINKS = 100_000


@dataclass(frozen=True)
class LinearDrift:
    """c(t) = start + velocity t (m, m/s, global)."""

    start: FloatArray
    velocity: FloatArray

    def position(self, t: ArrayLike) -> FloatArray:
        tt = np.asarray(t, dtype=float)[..., None]
        return self.start + self.velocity * tt

    def velocity_at(self, t: ArrayLike) -> FloatArray:
        tt = np.asarray(t, dtype=float)[..., None]
        return np.broadcast_to(self.velocity, tt.shape[:-1] + (3,)).copy()

    def at_times(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(c(t), cdot(t)) at each time (T,), s -> (T, 3), (T, 3)."""
        return self.start + self.velocity * t[:, None], np.tile(self.velocity, (t.size, 1))


@dataclass(frozen=True)
class CircularPath:
    """c(t) = centre + radius (cos(phase + w t) u + sin(phase + w t) v), u ⟂ v unit vectors."""

    centre: FloatArray
    radius: float
    angular_speed: float  # rad/s
    phase: float
    u: FloatArray
    v: FloatArray

    def position(self, t: ArrayLike) -> FloatArray:
        a = self.phase + self.angular_speed * np.asarray(t, dtype=float)[..., None]
        return self.centre + self.radius * (np.cos(a) * self.u + np.sin(a) * self.v)

    def velocity_at(self, t: ArrayLike) -> FloatArray:
        a = self.phase + self.angular_speed * np.asarray(t, dtype=float)[..., None]
        return self.radius * self.angular_speed * (-np.sin(a) * self.u + np.cos(a) * self.v)

    def at_times(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(c(t), cdot(t)) at each time (T,), s -> (T, 3), (T, 3), with ``math``'s sine and
        cosine (numpy's may differ in the last bit from one array length to another)."""
        a = (self.phase + self.angular_speed * t).tolist()
        c = np.array([math.cos(x) for x in a])[:, None]
        s = np.array([math.sin(x) for x in a])[:, None]
        w = self.radius * self.angular_speed
        return self.centre + self.radius * (c * self.u + s * self.v), w * (c * self.v - s * self.u)


@dataclass(frozen=True)
class Evasive:
    """Constant-acceleration segments: acceleration ``accelerations[k]`` holds on
    ``[switch_times[k], switch_times[k+1])`` (``switch_times[0] == 0``)."""

    start: FloatArray
    initial_velocity: FloatArray
    switch_times: FloatArray  # (K,)
    accelerations: FloatArray  # (K, 3)
    _knots: tuple[FloatArray, FloatArray] = field(init=False, repr=False, compare=False)
    _times: list[float] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # Position and velocity at every switch time, so evaluation is a lookup + one segment.
        p, v = [np.asarray(self.start, float)], [np.asarray(self.initial_velocity, float)]
        for k in range(1, len(self.switch_times)):
            h = self.switch_times[k] - self.switch_times[k - 1]
            a = self.accelerations[k - 1]
            p.append(p[-1] + v[-1] * h + 0.5 * a * h * h)
            v.append(v[-1] + a * h)
        object.__setattr__(self, "_knots", (np.array(p), np.array(v)))
        object.__setattr__(self, "_times", [float(x) for x in self.switch_times])

    def _segment(self, t: ArrayLike) -> tuple[NDArray[np.intp], FloatArray]:
        tt = np.asarray(t, dtype=float)
        k = np.clip(np.searchsorted(self.switch_times, tt, side="right") - 1, 0, None)
        return k, (tt - self.switch_times[k])[..., None]

    def position(self, t: ArrayLike) -> FloatArray:
        k, h = self._segment(t)
        p, v = self._knots
        return p[k] + v[k] * h + 0.5 * self.accelerations[k] * h * h

    def velocity_at(self, t: ArrayLike) -> FloatArray:
        k, h = self._segment(t)
        return self._knots[1][k] + self.accelerations[k] * h

    def at_times(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(c(t), cdot(t)) at each time (T,), s -> (T, 3), (T, 3)."""
        k = np.maximum(np.searchsorted(self.switch_times, t, side="right") - 1, 0)
        h = (t - np.asarray(self._times)[k])[:, None]
        p, v = self._knots
        a = self.accelerations[k]
        return p[k] + v[k] * h + (0.5 * h * h) * a, v[k] + a * h


Translation = LinearDrift | CircularPath | Evasive


@dataclass(frozen=True)
class TargetTrajectory:
    """The full rigid-body motion of the target.

    Attributes:
        translation: motion of the centre of rotation c(t).
        initial_rotation: R0, target frame -> global, (3, 3).
        spin_axis: unit axis of the constant angular velocity, global, (3,).
        spin_rate: angular speed, rad/s (0 for a non-tumbling target).
        capture_offset: capture point relative to the centre of rotation, target frame, m, (3,).
    """

    translation: Translation
    initial_rotation: FloatArray = field(default_factory=lambda: np.eye(3))
    spin_axis: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    spin_rate: float = 0.0
    capture_offset: FloatArray = field(default_factory=lambda: np.zeros(3))
    _kx: FloatArray = field(init=False, repr=False, compare=False)
    _kx2: FloatArray = field(init=False, repr=False, compare=False)
    _r0: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # Constants of `states`: Rodrigues' K and K^2, R0 r.
        k = np.asarray(self.spin_axis, dtype=float)
        k = k / np.linalg.norm(k)
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        object.__setattr__(self, "_kx", kx)
        object.__setattr__(self, "_kx2", kx @ kx)
        object.__setattr__(self, "_r0", self.initial_rotation @ self.capture_offset)

    def states(
        self, t: FloatArray, points_target: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray | None]:
        """Everything the env needs at each time (T,): X_T (T, 3), Xdot_T (T, 3), R(t)
        (T, 3, 3), and with ``points_target`` (N, 3) those points in the global frame at each
        time, ``X_T + points_target @ R(t).T`` (T, N, 3) (None without).

        The same quantities as `position`, `velocity` and `rotation` (to rounding: tests check
        they agree), with ``math``'s sine and cosine and each small matrix product as a stack,
        which numpy computes one matrix at a time: a time's numbers do not depend on the other
        times asked for, and ``points`` is, bit for bit, ``X_T + points_target @ R(t).T`` of
        that time's rows (what a live camera is given).
        """
        tt = np.asarray(t, dtype=float).reshape(-1)
        c, c_dot = self.translation.at_times(tt)
        seen = None  # points_target turned to the global frame's axes, (N, 3) or (T, N, 3)
        if self.spin_rate == 0.0:
            position, velocity = c + self._r0, c_dot
            rotation = np.broadcast_to(self.initial_rotation, (tt.size, 3, 3)).copy()
            if points_target is not None:
                seen = points_target @ self.initial_rotation.T
        else:
            a = (self.spin_rate * tt).tolist()
            sin = np.array([math.sin(x) for x in a]).reshape(-1, 1, 1)
            cos = np.array([math.cos(x) for x in a]).reshape(-1, 1, 1)
            spin = _EYE3 + sin * self._kx + (1.0 - cos) * self._kx2
            offset = np.matmul(spin, self._r0[:, None])[:, :, 0]
            turn = np.matmul(self._kx, offset[:, :, None])[:, :, 0]
            position, velocity = c + offset, c_dot + self.spin_rate * turn
            rotation = spin @ self.initial_rotation
            if points_target is not None:
                seen = points_target @ rotation.transpose(0, 2, 1)
        points = None if seen is None else position[:, None, :] + seen
        return position, velocity, rotation, points

    def rotations(self, t: FloatArray) -> FloatArray:
        """R(t) for times (N,) -> (N, 3, 3): `states`' rotation, to rounding."""
        tt = np.asarray(t, dtype=float)
        if self.spin_rate == 0.0:
            return np.broadcast_to(self.initial_rotation, (*tt.shape, 3, 3)).copy()
        a = (self.spin_rate * tt)[..., None, None]
        spin = _EYE3 + np.sin(a) * self._kx + (1.0 - np.cos(a)) * self._kx2
        return spin @ self.initial_rotation

    @property
    def angular_velocity(self) -> FloatArray:
        """omega, rad/s, global frame, (3,)."""
        return self.spin_rate * np.asarray(self.spin_axis, dtype=float)

    def rotation(self, t: float) -> FloatArray:
        """R(t): target frame -> global, (3, 3)."""
        return axis_angle_to_matrix(self.spin_axis, self.spin_rate * t) @ self.initial_rotation

    def _offsets(self, t: ArrayLike) -> FloatArray:
        """R(t) r for scalar or (N,) t -> (3,) or (N, 3), m."""
        tt = np.asarray(t, dtype=float)
        r0 = self.initial_rotation @ self.capture_offset
        if self.spin_rate == 0.0 or not np.any(r0):
            return np.broadcast_to(r0, tt.shape + (3,)).copy()
        # Rodrigues applied to a vector, vectorised over t.
        k = np.asarray(self.spin_axis, dtype=float)
        a = self.spin_rate * tt[..., None]
        return r0 * np.cos(a) + np.cross(k, r0) * np.sin(a) + k * (k @ r0) * (1.0 - np.cos(a))

    def position(self, t: ArrayLike) -> FloatArray:
        """X_T(t): capture point, global, m; (3,) or (N, 3)."""
        if self.spin_rate == 0.0:  # R(t) r = R0 r at every t (the same numbers as _offsets)
            return self.translation.position(t) + self._r0
        return self.translation.position(t) + self._offsets(t)

    def velocity(self, t: ArrayLike) -> FloatArray:
        """Xdot_T(t) = cdot + omega x (R r), global, m/s; (3,) or (N, 3)."""
        return self.translation.velocity_at(t) + np.cross(self.angular_velocity, self._offsets(t))

    def feature_points(self, t: float, points_target: FloatArray) -> FloatArray:
        """Feature points (4, 3) given in the target frame -> global, m, (4, 3)."""
        return self.position(t) + points_target @ self.rotation(t).T


FEATURE_POINTS = {
    # DESIGN.md defaults, target frame, m. The first point is the capture point.
    "non_coplanar": np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.05]]),
    "coplanar_square": np.array(
        [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.1, 0.1, 0.0], [0.0, 0.1, 0.0]]
    ),
}


def random_unit_vector(rng: np.random.Generator) -> FloatArray:
    """A direction drawn uniformly on the unit sphere, (3,)."""
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def random_rotation(rng: np.random.Generator) -> FloatArray:
    """A rotation drawn uniformly (normalised Gaussian quaternion), (3, 3)."""
    w, x, y, z = _unit4(rng)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _unit4(rng: np.random.Generator) -> FloatArray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def sample_trajectory(
    cfg, rng: np.random.Generator, anchor: ArrayLike, horizon: float
) -> TargetTrajectory:
    """Draw one true trajectory from a scenario's target ranges.

    Args:
        cfg: the scenario's ``TargetConfig`` (ranges; degrees converted here).
        rng: the environment's seeded generator (every draw comes from it, in a fixed order).
        anchor: the home end-effector position the initial offset is measured from, global, m.
        horizon: episode limit, s (how far the evasive manoeuvre schedule must reach).
    """
    start = np.asarray(anchor, dtype=float) + rng.uniform(*cfg.initial_offset) * random_unit_vector(
        rng
    )
    r0 = random_rotation(rng)
    spin_axis = random_unit_vector(rng)
    spin_rate = np.radians(rng.uniform(*cfg.tumble_rate_deg))
    offset = rng.uniform(*cfg.capture_offset) * random_unit_vector(rng)
    centre0 = start - r0 @ offset
    speed = rng.uniform(*cfg.speed)
    direction = random_unit_vector(rng)
    translation: Translation
    if cfg.motion == "circular":
        radius = rng.uniform(*cfg.circle_radius)
        omega = rng.uniform(*cfg.circle_speed) / radius * rng.choice([-1.0, 1.0])
        u = random_unit_vector(rng)
        v = np.cross(u, random_unit_vector(rng))
        v /= np.linalg.norm(v)
        phase = rng.uniform(0.0, 2.0 * np.pi)
        centre = centre0 - radius * (np.cos(phase) * u + np.sin(phase) * v)
        translation = CircularPath(centre, radius, omega, phase, u, v)
    elif cfg.motion == "evasive":
        shortest = cfg.jink_interval[0]
        if not shortest > 0.0 or horizon / shortest > MAX_JINKS:
            raise ValueError(
                f"jink_interval {tuple(cfg.jink_interval)} s over {horizon} s: expected at most "
                f"{MAX_JINKS} acceleration changes, each interval > 0"
            )
        times = [0.0]
        while times[-1] < horizon:
            times.append(times[-1] + rng.uniform(*cfg.jink_interval))
        accelerations = np.array(
            [rng.uniform(*cfg.jink_acceleration) * random_unit_vector(rng) for _ in times]
        )
        translation = Evasive(centre0, speed * direction, np.array(times), accelerations)
    else:  # drift and tumbling share a drifting centre
        translation = LinearDrift(centre0, speed * direction)
    return TargetTrajectory(translation, r0, spin_axis, float(spin_rate), offset)
