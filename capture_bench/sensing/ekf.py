"""The 12-state extended Kalman filter of the paper (section 2, eqs. 3-7) on filterpy.

State, in the camera frame, in the paper's order::

    X = (x, x_dot, y, y_dot, z, z_dot, theta_x, theta_x_dot, theta_y, theta_y_dot,
         theta_z, theta_z_dot)

where (x, y, z) is the origin of the target frame (the capture point), metres, and the Euler angles
give ``R_ct = Rz Ry Rx``, radians. Constant-velocity model per coordinate (eqs. 3-5) driven by
white acceleration noise ``omega`` with covariance ``Q = diag(sigma_a^2 x3, sigma_alpha^2 x3)``;
filterpy's process noise is ``B Q B^T``. Measurement (eq. 6): the image points of the four feature
points by eq. 2, flattened as (x_m1, z_m1, ..., x_m4, z_m4), with noise ``R = sigma_m^2 I_8``;
``H`` is the analytic Jacobian (`capture_bench.sensing.photogrammetry.project_pose`, on the
feature points' projection table, computed once); h and H come from one evaluation per update and
are written into arrays the filter owns. The filter equations (eq. 7) are those of filterpy's
``ExtendedKalmanFilter.predict`` and ``update``, run by
`LeanExtendedKalmanFilter`, a subclass that computes them
with fewer numpy calls (tests check it against filterpy's own methods step for step). That module,
and so filterpy (whose import pulls in ``scipy.stats``, a slow import), is imported when the first
`TargetEKF` is built: the batched estimator (`capture_bench.sensing.estimator_batch`),
which training runs on, uses this module's model and never needs it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.photogrammetry import pose_projection, project_pose, projection_table

FloatArray = NDArray[np.float64]

POSE_INDEX = np.array([0, 2, 4, 6, 8, 10])  # (x, y, z, theta_x, theta_y, theta_z) in X
POSITION_VELOCITY_INDEX = np.array([0, 2, 4, 1, 3, 5])  # (x, y, z, x_dot, y_dot, z_dot) in X
_PV_BLOCK = np.ix_(POSITION_VELOCITY_INDEX, POSITION_VELOCITY_INDEX)


_EYE12 = np.eye(12)
# Flat indices into a (12, 12) matrix: the t_s entries of A (eq. 4), and the 2 x 2 block
# (q q, q q_dot, q_dot q, q_dot q_dot) of each coordinate q in B Q B' (eq. 5).
_A_RATE_ENTRIES = POSE_INDEX * 12 + POSE_INDEX + 1
_BQB_ENTRIES = (POSE_INDEX * 13)[:, None] + np.array([0, 1, 12, 13])


def transition_matrices(dt: float) -> tuple[FloatArray, FloatArray]:
    """``A`` (12, 12) and ``B`` (12, 6) of eqs. 4-5 for a sampling interval ``dt`` (s)."""
    b = np.zeros((12, 6))
    b[POSE_INDEX, np.arange(6)] = 0.5 * dt * dt  # eq. 5: [t_s^2 / 2, t_s] blocks
    b[POSE_INDEX + 1, np.arange(6)] = dt
    return state_transition(dt), b


def state_transition(dt: float) -> FloatArray:
    """``A`` (12, 12) of eq. 4 for a sampling interval ``dt`` (s): [[1, t_s], [0, 1]] blocks."""
    a = _EYE12.copy()
    a.put(_A_RATE_ENTRIES, dt)
    return a


def process_noise(dt: float, variances: Sequence[float]) -> FloatArray:
    """``B Q B'`` (12, 12) of eq. 5 for a sampling interval ``dt`` (s) and ``Q = diag(variances)``
    (sigma_a^2 x3, sigma_alpha^2 x3; (m/s^2)^2 and (rad/s^2)^2).

    B has one non-zero per row (``t_s^2 / 2`` or ``t_s``), so every entry of the matrix product
    ``B @ Q @ B.T`` is one product ``(b_i q_j) b_l`` and the rest exact zeros: written out, the
    same floats, bit for bit (``tests/test_estimator.py``), without two matrix products.
    """
    half = 0.5 * dt * dt
    values: list[float] = []
    for q in variances:
        half_q, dt_q = half * q, dt * q  # (B Q)[i, j] = b_i q_j
        values += (half_q * half, half_q * dt, dt_q * half, dt_q * dt)
    out = np.zeros((12, 12))
    out.put(_BQB_ENTRIES, values)
    return out


def measurement_sigma(noise_px: float, pixel_pitch: float, noise_floor_px: float) -> float:
    """sigma_m of R = sigma_m^2 I (eq. 6), metres: ``max(noise_px, noise_floor_px)`` pixels."""
    return max(noise_px, noise_floor_px) * pixel_pitch


def wrap_angle(angle: FloatArray | float) -> FloatArray | float:
    """Euler angle(s) moved into [-pi, pi) by whole turns (h is 2 pi-periodic in them)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def default_initial_covariance() -> FloatArray:
    """Prior covariance (12, 12) around a photogrammetry pose, velocities unknown (zero mean).

    Standard deviations: position 0.05 m, angles 0.2 rad, linear velocity 0.5 m/s, angular
    velocity 1 rad/s.
    """
    sd = np.empty(12)
    sd[POSE_INDEX[:3]] = 0.05
    sd[POSE_INDEX[3:]] = 0.2
    sd[POSE_INDEX[:3] + 1] = 0.5
    sd[POSE_INDEX[3:] + 1] = 1.0
    return np.diag(sd**2)


class TargetEKF:
    """The paper's EKF for the target's pose and rates in the camera frame.

    Args:
        feature_points: feature points in the target frame, metres, shape (4, 3).
        focal_length: f, metres.
        pixel_pitch: metres per pixel.
        noise_px: image noise standard deviation assumed by R, pixels.
        sigma_acceleration: sigma_a of the white linear acceleration noise, m/s^2.
        sigma_angular_acceleration: sigma_alpha of the white angular acceleration noise, rad/s^2.
        noise_floor_px: R uses ``max(noise_px, noise_floor_px)`` so a noise-free camera still gives
            a well-conditioned filter.
    """

    def __init__(
        self,
        feature_points: ArrayLike,
        focal_length: float = 0.008,
        pixel_pitch: float = 3.75e-6,
        noise_px: float = 1.0,
        sigma_acceleration: float = 0.01,
        sigma_angular_acceleration: float = 0.01,
        noise_floor_px: float = 0.25,
    ) -> None:
        self.feature_points = np.array(feature_points, dtype=float).reshape(-1, 3)
        self.focal_length = float(focal_length)
        n_z = 2 * self.feature_points.shape[0]
        sigma_m = measurement_sigma(noise_px, pixel_pitch, noise_floor_px)
        # Q = cov(omega), diagonal (eq. 5): its six variances
        self._q = (sigma_acceleration**2,) * 3 + (sigma_angular_acceleration**2,) * 3
        from capture_bench.sensing.lean_ekf import LeanExtendedKalmanFilter  # filterpy (above)

        self._kf = LeanExtendedKalmanFilter(dim_x=12, dim_z=n_z)
        self._kf.R = np.eye(n_z) * sigma_m**2
        self._dt: float | None = None
        self._table = projection_table(self.feature_points, self.focal_length)
        n = self.feature_points.shape[0]
        self._H = np.zeros((n_z, 12))  # the rate columns (odd) stay zero: they do not enter eq. 2
        self._H_pose = self._H.reshape(n, 2, 6, 2)[:, :, :, 0]  # view: [point, (x_m, z_m), pose]
        self._hx_for: FloatArray | None = None  # state whose h(X) is cached in _hx
        self._hx = np.zeros(n_z)
        self._hx_points = self._hx.reshape(n, 2)  # view: [point, (x_m, z_m)]
        self.nis = float("nan")
        self.prior_in_front = True  # every feature point was beyond the lens at the last update
        self.initialised = False

    # -- set-up -------------------------------------------------------------------------------
    def initialise(self, pose: ArrayLike, covariance: ArrayLike | None = None) -> None:
        """Start from a pose (6,) in the camera frame, rates zero.

        Args:
            pose: (x, y, z, theta_x, theta_y, theta_z), metres and radians (e.g. photogrammetry).
            covariance: prior P0 (12, 12) in state order; default
                `default_initial_covariance` (large velocity variance).
        """
        x = np.zeros(12)
        x[POSE_INDEX] = np.asarray(pose, dtype=float)
        self._kf.x = x
        p0 = default_initial_covariance() if covariance is None else covariance
        self._kf.P = np.array(p0, dtype=float).reshape(12, 12)
        self.nis = float("nan")
        self.initialised = True

    def set_state(
        self, state: ArrayLike | None = None, covariance: ArrayLike | None = None
    ) -> None:
        """Replace X and/or P as given (copies), keeping everything else (``initialised``, NIS,
        the last dt): a restart from a full state, or a test that puts the filter in a given
        (say non-finite) state.

        Args:
            state: X (12,) in the paper's order (metres, m/s, radians, rad/s); None: kept.
            covariance: P (12, 12) in state order; None: kept.
        """
        if state is not None:
            self._kf.x = np.array(state, dtype=float).reshape(12)
        if covariance is not None:
            self._kf.P = np.array(covariance, dtype=float).reshape(12, 12)

    # -- filter steps -------------------------------------------------------------------------
    def predict(self, dt: float) -> None:
        """Propagate by ``dt`` seconds with eq. 3 (A and B are rebuilt only when dt changes)."""
        if dt < 0:
            raise ValueError(f"dt must be >= 0, got {dt}")
        if dt != self._dt:
            self._kf.F = state_transition(dt)
            self._kf.Q = process_noise(dt, self._q)
            self._dt = dt
        self._kf.predict()

    def update(self, image_points: ArrayLike | None) -> None:
        """Correct with one image (eq. 7); None (lost frame) leaves the prediction as it is.

        A point whose row is NaN (a marker not found) is left out of the update: its rows of H
        are zero and its innovation is zero, so S is block diagonal, its columns of K are zero and
        the update is the one with the seen points' rows of eq. 6 alone (the NIS then has
        2 x seen degrees of freedom).

        Args:
            image_points: measured ``[x_m, z_m]`` of the feature points, metres, shape (4, 2);
                NaN rows for points not seen (at least one seen).
        """
        if image_points is None:
            self._kf.update(None, self.jacobian, self.measure)
            self.nis = float("nan")
            return
        z = np.asarray(image_points, dtype=float).reshape(-1)
        missing = np.isnan(z)
        if missing.any():
            kf = self._kf
            h_seen = self.jacobian(kf.x).copy()  # caches h(X) for measure() at kf.x
            h_seen[missing] = 0.0
            z = np.where(missing, self._hx, z)  # z - h(X) = 0 where not seen
            kf.update(z, lambda _x: h_seen, self.measure)
        else:
            self._kf.update(z, self.jacobian, self.measure)
        y = self._kf.y
        self.nis = float(y @ self._kf.SI @ y)
        x = self._kf.x
        for i in (6, 8, 10):  # keep the Euler angles in [-pi, pi); h is 2 pi-periodic in them
            if not -math.pi <= x[i] < math.pi:
                x[i] = wrap_angle(x[i])

    def jacobian(self, x: FloatArray) -> FloatArray:
        """H = dh/dX (2N, 12) at a state X (12,), the callback the filter's update calls first.

        Metres of image per metre / radian of state; the rate columns (odd) are zero. Returns the
        EKF's own array (overwritten by the next call); also sets `prior_in_front` and
        caches h(X) for `measure` at the same state object.
        """
        h, jt, depth = project_pose(x.tolist()[0::2], self._table)
        self.prior_in_front = bool(depth.min() > 0.0)
        self._H_pose[...] = jt.T  # (6, 2, N) -> (N, 2, 6)
        self._hx_points[...] = h.T
        self._hx_for = x
        return self._H

    def measure(self, x: FloatArray) -> FloatArray:
        """h(X) of eq. 6 at a state X (12,): image points (2N,) of the feature points, metres.

        The filter's update calls it after `jacobian`; at that same state object it returns
        the cached array (the EKF's own, overwritten by the next `jacobian`).
        """
        if x is self._hx_for:
            return self._hx
        return measurement(x, self.feature_points, self.focal_length)

    # -- read-out -----------------------------------------------------------------------------
    @property
    def x(self) -> FloatArray:
        """X (12,), the filter's own array (read only; `initialise` or `set_state`
        sets it)."""
        return self._kf.x

    @property
    def P(self) -> FloatArray:
        """P (12, 12), the filter's own array (read only)."""
        return self._kf.P

    @property
    def F(self) -> FloatArray:
        """F (12, 12), the state transition A of eq. 3 for the dt of the last `predict`
        (identity before any), the filter's own array (read only)."""
        return self._kf.F

    @property
    def Q(self) -> FloatArray:
        """Q = B diag(sigma_a^2 (x3), sigma_alpha^2 (x3)) B' (12, 12) for the dt of the last
        `predict` (identity before any), the filter's own array (read only)."""
        return self._kf.Q

    @property
    def R(self) -> FloatArray:
        """R (2N, 2N), the image noise covariance, m^2 (diagonal), the filter's own array (read
        only)."""
        return self._kf.R

    @property
    def state(self) -> FloatArray:
        """X (12,), a copy, in the paper's order."""
        return np.array(self._kf.x, dtype=float).reshape(12)

    @property
    def covariance(self) -> FloatArray:
        """P (12, 12), a copy."""
        return np.array(self._kf.P, dtype=float)

    @property
    def pose(self) -> FloatArray:
        """(x, y, z, theta_x, theta_y, theta_z) in the camera frame, metres and radians, (6,)."""
        return self._kf.x[0::2].copy()

    @property
    def position(self) -> FloatArray:
        """Target origin in the camera frame, metres, (3,)."""
        return self._kf.x[0:6:2].copy()

    @property
    def velocity(self) -> FloatArray:
        """Target origin velocity in the camera frame, m/s, (3,)."""
        return self._kf.x[1:6:2].copy()

    @property
    def position_velocity_covariance(self) -> FloatArray:
        """Covariance (6, 6) of (position, velocity) in the camera frame, m and m/s."""
        return self._kf.P[_PV_BLOCK]

    @property
    def is_finite(self) -> bool:
        """Whether the state and covariance are finite."""
        return math.isfinite(self._kf.x.sum() + self._kf.P.sum())  # a NaN or inf anywhere shows


def measurement(x: FloatArray, feature_points: FloatArray, focal_length: float) -> FloatArray:
    """h(X) of eq. 6 for a state X (12,): image points flattened (2N,), metres."""
    return pose_projection(np.asarray(x)[POSE_INDEX], feature_points, focal_length)[0]


def measurement_jacobian(
    x: FloatArray, feature_points: FloatArray, focal_length: float
) -> FloatArray:
    """H = dh/dX (2N, 12), analytic (the rate columns are zero)."""
    jac = pose_projection(np.asarray(x)[POSE_INDEX], feature_points, focal_length)[1]
    out = np.zeros((jac.shape[0], 12))
    out[:, POSE_INDEX] = jac
    return out
