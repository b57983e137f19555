"""Target state estimation: photogrammetry -> EKF, output in the global frame (paper section 2).

Three sources, chosen by name:

* ``"ekf"`` (the paper): the first frame whose photogrammetry solution is accepted initialises the
  `TargetEKF` (that step reports the photogrammetry position, zero
  velocity and the prior covariance); afterwards each step is ``predict(dt)`` then ``update`` with
  the frame (a missing frame is a predict-only step). A frame in which some feature points
  were not found (the rendered camera's; NaN rows) updates with the points seen, or is a
  predict-only step with ``partial_frames="predict"``; it never initialises (photogrammetry needs
  every point).
* ``"photogrammetry"`` (raw-measurement ablation): the per-frame pose, warm-started from the
  previous solution; velocity by finite difference of consecutive solutions over the time between
  them (zero after the first solution); no covariance. Without a frame the last solution is held.
* ``"truth"`` (privileged ablation): the true position and velocity passed in.

The estimate is moved to the global frame by eqs. 11-12 with the camera fixed (T-dot = 0):
``X_T = c + R_gc p_C``, ``X_T-dot = R_gc v_C``, covariance rotated blockwise.

Acceptance of a photogrammetry solution: converged, and its image residual RMS at most
``ACCEPT_RESIDUAL_SIGMAS`` times the assumed pixel noise (floored like the EKF's R).

Divergence rule (``"ekf"``): the filter is declared diverged when its state or covariance becomes
non-finite (or filterpy cannot invert the innovation covariance), when a feature point of the
predicted state lies behind the lens at an update, or when the NIS of
``DIVERGENCE_FRAMES`` consecutive updates exceeds ``NIS_LIMIT`` (chi-square with 8 degrees of
freedom exceeds 100 with probability below 1e-17). On the step it is detected, and on every later
step with a frame, the estimator tries to re-initialise from photogrammetry of that frame; every
step on which it cannot reports status ``"diverged"`` with ``valid = False``.

Invalid estimates (``"initialising"``, ``"diverged"``) carry NaN position and velocity: the caller
must check ``valid``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import lapack

from capture_bench.sensing.camera import CameraModel, Frame
from capture_bench.sensing.ekf import POSITION_VELOCITY_INDEX, TargetEKF, measurement_sigma
from capture_bench.sensing.photogrammetry import PoseSolution, solve_pose
from capture_bench.sensing.sources import SOURCES

FloatArray = NDArray[np.float64]

STATUSES = ("ok", "predicting", "initialising", "diverged")
#: What the EKF does with a frame missing some feature points (see `TargetEstimator`).
PARTIAL_FRAME_RULES = ("update", "predict")
NIS_LIMIT = 100.0
DIVERGENCE_FRAMES = 5
ACCEPT_RESIDUAL_SIGMAS = 5.0
NOISE_FLOOR_PX = 0.25


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


def acceptance_residual(camera_model: CameraModel, noise_px: float) -> float:
    """Largest accepted photogrammetry residual RMS, metres on the image plane."""
    sigma_m = measurement_sigma(noise_px, camera_model.pixel_pitch, NOISE_FLOOR_PX)
    return ACCEPT_RESIDUAL_SIGMAS * sigma_m


def solution_accepted(converged: Any, residual_rms: Any, max_residual: float) -> Any:
    """The acceptance rule: converged with residual RMS <= ``max_residual`` (scalars or arrays)."""
    return converged & (residual_rms <= max_residual)


def state_to_global(rotation: FloatArray) -> FloatArray:
    """EKF state X (12,) -> global-frame (position, velocity) less the camera position, (6, 12).

    ``blockdiag(R_gc, R_gc) @ S`` with S selecting (x, y, z, x_dot, y_dot, z_dot) from X
    (eqs. 11-12, T-dot = 0); add the camera position to the first three rows' result.
    """
    select = np.zeros((6, 12))
    select[np.arange(6), POSITION_VELOCITY_INDEX] = 1.0
    rot6 = np.zeros((6, 6))
    rot6[:3, :3] = rot6[3:, 3:] = rotation
    return rot6 @ select


def _invalid(status: str) -> TargetEstimate:
    nan = np.full(3, np.nan)
    return TargetEstimate(nan, nan.copy(), None, False, status)


class TargetEstimator:
    """Turns camera frames into a global-frame estimate of the capture point, one episode's.

    The ``"ekf"`` source for many episodes at once is
    `BatchedTargetEstimator` (tested equal to this
    one step for step); this one stays for a single episode, where it is the faster of the
    two (why: `capture_bench.sensing.estimator_batch`; the figures:
    ``benchmarks/bench_estimator_batch.py``, the table "The batched estimator" of
    ``docs/speed.md``).

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
        sol = solve_pose(image, self.feature_points, f, guess)
        if guess is not None and not solution_accepted(
            sol.converged, sol.residual_rms, self.max_residual
        ):
            sol = solve_pose(image, self.feature_points, f, None)
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
