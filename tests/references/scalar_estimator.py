"""The scalar estimator of one episode, an independent reference for `TargetEstimator`.

The paper's EKF (section 2, eqs. 3-7) on filterpy's own ``ExtendedKalmanFilter`` (its predict
and update, in the paper's state order), photogrammetry initialising it, the divergence rule and
the global-frame output (eqs. 11-12), one frame at a time; and the errors and NEES of one estimate
in ``math`` and LAPACK. `capture_bench.sensing.estimator.TargetEstimator` must give each of its
rows the numbers this gives one episode, to rounding (``tests/test_estimator_rows.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import lapack

from capture_bench.sensing.camera import CameraModel, Frame
from capture_bench.sensing.ekf import (
    POSE_INDEX,
    POSITION_VELOCITY_INDEX,
    default_initial_covariance,
    measurement,
    measurement_sigma,
    process_noise,
    state_transition,
    wrap_angle,
)
from capture_bench.sensing.estimator import (
    DIVERGENCE_FRAMES,
    NIS_LIMIT,
    NOISE_FLOOR_PX,
    PARTIAL_FRAME_RULES,
    acceptance_residual,
    solution_accepted,
    state_to_global,
)
from capture_bench.sensing.photogrammetry import (
    PoseSolution,
    project_pose,
    projection_table,
    solve_poses,
)
from capture_bench.sensing.sources import SOURCES

FloatArray = NDArray[np.float64]
_PV_BLOCK = np.ix_(POSITION_VELOCITY_INDEX, POSITION_VELOCITY_INDEX)


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
        self._kf = ExtendedKalmanFilter(dim_x=12, dim_z=n_z)
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


@dataclass
class TargetEstimate:
    """The estimator's output for one step, global frame.

    Attributes:
        position: capture point, metres, shape (3,) (NaN when not valid).
        velocity: capture point velocity, m/s, shape (3,) (NaN when not valid).
        covariance: (6, 6) covariance of (position, velocity), m and m/s, or None where the source
            has none (photogrammetry, truth, invalid).
        valid: whether position and velocity hold an estimate.
        status: "ok" (a frame was used this step), "predicting" (no frame this step; the estimate
            is a prediction or the held last solution), "initialising" (no accepted photogrammetry
            yet), or "diverged" (see the module docstring).
    """

    position: FloatArray
    velocity: FloatArray
    covariance: FloatArray | None
    valid: bool
    status: str


def _invalid(status: str) -> TargetEstimate:
    nan = np.full(3, np.nan)
    return TargetEstimate(nan, nan.copy(), None, False, status)


class TargetEstimator:
    """Turns camera frames into a global-frame estimate of the capture point, one episode's.

    Args:
        camera_model: the (fixed) camera's geometry.
        feature_points: feature points in the target frame, metres, shape (4, 3).
        source: "ekf", "photogrammetry" or "truth".
        noise_px: image noise the estimator assumes, pixels (sets the EKF's R and acceptance).
        sigma_acceleration: EKF process noise sigma_a, m/s^2.
        sigma_angular_acceleration: EKF process noise sigma_alpha, rad/s^2.
        partial_frames: what the ``"ekf"`` source does with a frame in which some feature
            points were not found (NaN rows; the rendered camera's): ``"update"`` (default)
            corrects a running filter with the points seen, ``"predict"`` treats the frame as
            lost (a predict-only step). Either way such a frame cannot initialise the filter.
    """

    def __init__(
        self,
        camera_model: CameraModel,
        feature_points: ArrayLike,
        source: str = "ekf",
        noise_px: float = 1.0,
        sigma_acceleration: float = 0.01,
        sigma_angular_acceleration: float = 0.01,
        partial_frames: str = "update",
    ) -> None:
        if source not in SOURCES:
            raise ValueError(f"unknown estimator source {source!r}; valid sources: {SOURCES}")
        if partial_frames not in PARTIAL_FRAME_RULES:
            raise ValueError(
                f"unknown partial_frames {partial_frames!r}; valid: {PARTIAL_FRAME_RULES}"
            )
        self.partial_frames = partial_frames
        self.camera_model = camera_model
        self.feature_points = np.array(feature_points, dtype=float).reshape(-1, 3)
        self.source = source
        self.noise_px = float(noise_px)
        self.max_residual = acceptance_residual(camera_model, self.noise_px)  # image plane, m
        self.ekf = TargetEKF(
            self.feature_points,
            focal_length=camera_model.focal_length,
            pixel_pitch=camera_model.pixel_pitch,
            noise_px=self.noise_px,
            sigma_acceleration=sigma_acceleration,
            sigma_angular_acceleration=sigma_angular_acceleration,
            noise_floor_px=NOISE_FLOOR_PX,
        )
        self._state_to_global = state_to_global(camera_model.rotation)
        self._state_to_global_t = np.ascontiguousarray(self._state_to_global.T)
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next accepted frame initialises again."""
        self.ekf.initialised = False
        self.diverged = False
        self.reinitialisations = 0  # times the EKF restarted after a divergence
        self._high_nis = 0
        self.last_solution: PoseSolution | None = None
        self._pg_velocity = np.zeros(3)  # camera frame, m/s
        self._pg_elapsed = 0.0  # s since the last accepted photogrammetry solution

    # -- public step --------------------------------------------------------------------------
    def update(
        self,
        frame: Frame | None,
        dt: float,
        true_position: ArrayLike,
        true_velocity: ArrayLike,
    ) -> TargetEstimate:
        """One estimator step.

        Args:
            frame: the frame delivered this step, or None (lost, dropped, out of view, latency).
            dt: time since the previous step, s (the actual, possibly varying, control period).
            true_position: true capture point, global, m, (3,); read only by the "truth" source.
            true_velocity: true capture point velocity, global, m/s, (3,); "truth" source only.

        Returns:
            The `TargetEstimate` in the global frame.
        """
        if dt < 0:
            raise ValueError(f"dt must be >= 0, got {dt}")
        if self.source == "truth":
            return TargetEstimate(
                np.array(true_position, dtype=float).reshape(3),
                np.array(true_velocity, dtype=float).reshape(3),
                None,
                True,
                "ok",
            )
        image = None
        if frame is not None:
            image = np.asarray(frame.image_points, dtype=float)
            # A finite sum proves every entry finite (one reduction instead of two).
            finite = math.isfinite(image.sum()) or bool(np.isfinite(image).all())
            if image.shape != (self.feature_points.shape[0], 2):
                image = None
            elif not finite:
                seen = np.isfinite(image).all(axis=1)
                if self.source == "ekf" and self.partial_frames == "update" and seen.any():
                    image = np.where(seen[:, None], image, np.nan)  # a point: both or neither
                    return self._update_ekf_partial(image, dt)
                image = None
        if self.source == "photogrammetry":
            return self._update_photogrammetry(image, dt)
        return self._update_ekf(image, dt)

    # -- sources ------------------------------------------------------------------------------
    def solve(self, image: FloatArray, guess: FloatArray | None) -> PoseSolution | None:
        """Photogrammetry of one image; None unless converged with a plausible residual.

        A warm start that is rejected is retried cold (it may sit in a wrong local minimum).

        Args:
            image: measured ``[x_m, z_m]`` of the feature points, metres, shape (N, 2), finite.
            guess: pose (6,) in the camera frame to start from (metres, radians), or None for
                the cold multi-start.

        Returns:
            The accepted `PoseSolution` (pose in the camera frame), or None.
        """
        f = self.camera_model.focal_length
        first = None if guess is None else guess[None]
        sol = solve_poses(image[None], self.feature_points, f, first)[0]
        if guess is not None and not solution_accepted(
            sol.converged, sol.residual_rms, self.max_residual
        ):
            sol = solve_poses(image[None], self.feature_points, f, None)[0]
        if solution_accepted(sol.converged, sol.residual_rms, self.max_residual):
            return sol
        return None

    def _update_ekf(self, image: FloatArray | None, dt: float) -> TargetEstimate:
        ekf = self.ekf
        if not ekf.initialised or self.diverged:
            return self._try_initialise(image, "diverged" if self.diverged else "initialising")
        ekf.predict(dt)
        if image is None:
            if not ekf.is_finite:
                return self._declare_diverged(None)
            return self._ekf_estimate("predicting")
        try:
            ekf.update(image)
        except (ValueError, np.linalg.LinAlgError):  # non-finite or singular innovation covariance
            return self._declare_diverged(image)
        self._high_nis = self._high_nis + 1 if ekf.nis > NIS_LIMIT else 0
        if self._high_nis >= DIVERGENCE_FRAMES or not ekf.prior_in_front or not ekf.is_finite:
            return self._declare_diverged(image)
        return self._ekf_estimate("ok")

    def _update_ekf_partial(self, image: FloatArray, dt: float) -> TargetEstimate:
        """An EKF step with some feature points not seen (NaN rows): a running filter updates
        with the seen ones (`TargetEKF.update`); photogrammetry, which needs every point,
        cannot (re)initialise from such a frame."""
        if not self.ekf.initialised or self.diverged:
            return self._try_initialise(None, "diverged" if self.diverged else "initialising")
        return self._update_ekf(image, dt)

    def _declare_diverged(self, image: FloatArray | None) -> TargetEstimate:
        self.diverged = True
        return self._try_initialise(image, "diverged")

    def _try_initialise(self, image: FloatArray | None, failed_status: str) -> TargetEstimate:
        """Initialise the EKF from photogrammetry of ``image`` (paper: photogrammetry first); a
        frame with a point not seen cannot."""
        complete = image is not None and not np.isnan(image).any()
        sol = self.solve(image, None) if complete else None
        if sol is None:
            return _invalid(failed_status)
        self.last_solution = sol
        self.ekf.initialise(sol.pose)
        self.reinitialisations += self.diverged
        self.diverged = False
        self._high_nis = 0
        return self._ekf_estimate("ok")

    def _ekf_estimate(self, status: str) -> TargetEstimate:
        """The EKF's position, velocity and their covariance in the global frame (eqs. 11-12)."""
        m = self._state_to_global
        pv = m @ self.ekf.x
        cov = m @ self.ekf.P @ self._state_to_global_t
        return TargetEstimate(pv[:3] + self.camera_model.position, pv[3:], cov, True, status)

    def _update_photogrammetry(self, image: FloatArray | None, dt: float) -> TargetEstimate:
        self._pg_elapsed += dt
        previous = self.last_solution
        sol = None
        if image is not None:
            sol = self.solve(image, None if previous is None else previous.pose)
        if sol is None:
            if previous is None:
                return _invalid("initialising")
            return self._global(previous.pose[:3], self._pg_velocity, None, "predicting")
        if previous is not None and self._pg_elapsed > 0:
            self._pg_velocity = (sol.pose[:3] - previous.pose[:3]) / self._pg_elapsed
        self.last_solution = sol
        self._pg_elapsed = 0.0
        return self._global(sol.pose[:3], self._pg_velocity, None, "ok")

    def _global(
        self, p_cam: FloatArray, v_cam: FloatArray, cov: FloatArray | None, status: str
    ) -> TargetEstimate:
        """Eqs. 11-12 with T-dot = 0: camera-frame position/velocity -> global frame."""
        rot = self.camera_model.rotation
        position = rot @ p_cam + self.camera_model.position  # eq. 11
        velocity = rot @ v_cam  # eq. 12, T-dot = 0
        return TargetEstimate(position, velocity, cov, True, status)


def normalised_error_squared(error: NDArray[np.float64], covariance: NDArray[np.float64]) -> float:
    """NEES ``e^T P^-1 e`` by a Cholesky solve (P symmetric positive definite); NaN if P is not.

    LAPACK directly, every EKF step: far cheaper on a 6 x 6 matrix than ``np.linalg.solve``,
    whose per-call handling outweighs the arithmetic at that size.
    """
    chol, info = lapack.dpotrf(covariance)
    if info != 0:
        return math.nan
    w, _ = lapack.dpotrs(chol, error)
    return float(error @ w)


def estimate_errors_scalar(
    estimate: TargetEstimate, true_position: FloatArray, true_velocity: FloatArray
) -> tuple[float, float, float]:
    """`estimate_errors` of one estimate, in scalar ``math`` and LAPACK."""
    if not estimate.valid:
        return math.nan, math.nan, math.nan
    pos_err = math.dist(estimate.position.tolist(), true_position.tolist())
    vel_err = math.dist(estimate.velocity.tolist(), true_velocity.tolist())
    nees = math.nan
    if estimate.covariance is not None:
        e = np.concatenate([estimate.position - true_position, estimate.velocity - true_velocity])
        nees = normalised_error_squared(e, estimate.covariance)
    return pos_err, vel_err, nees
