"""A real camera's geometry errors: lens distortion and an episode's calibration error.

**Lens distortion** is Brown-Conrady's, in OpenCV's convention (``cv2.projectPoints``,
``cv2.undistortPoints``), on normalised coordinates ``(x', y') = ((u - c_u), (v - c_v)) / F``
with ``F = f / pitch`` and ``(c_u, c_v)`` the principal point (`capture_bench.sensing.pixels`:
OpenCV's x' is ``-x_m / f``, its y' is ``z_m / f``)::

    r^2 = x'^2 + y'^2
    x'' = x' (1 + k1 r^2 + k2 r^4) + 2 p1 x' y' + p2 (r^2 + 2 x'^2)
    y'' = y' (1 + k1 r^2 + k2 r^4) + p1 (r^2 + 2 y'^2) + 2 p2 x' y'

**Calibration error**: the camera that takes an episode's images (the *true* camera,
`TrueCamera`) differs from the calibrated one the estimator knows (the *nominal* camera: the
scenario's pose, f, the image centre as principal point and the scenario's distortion
coefficients) by an error drawn once per episode (`CalibrationSpread.draw`): focal length
(relative), principal point (pixels), k1 (absolute), orientation (a small rotation about the
camera's axes) and position (global, metres). A calibrated system reads a marker's measured
pixel with the nominal calibration: undistorted with the nominal coefficients
(`Distortion.remove`) and mapped to eq. 2's image plane with the nominal f and principal point
(`TrueCamera.calibrated_points`).

The analytic camera (`capture_bench.sensing.camera.Camera`) projects the feature points through
the true camera and adds its noise to the pixels it records (`TrueCamera.observe`). The rendered
camera renders the true camera's pinhole (its pose and f) and applies the lens at the point
level: a detected centroid, a pinhole pixel, is distorted with the true coefficients
and moved by the principal point's error (`TrueCamera.measured_pixels`). Distorting the image
instead would move the blob's centroid by the distortion's curvature over the blob as well;
``tests/test_calibration_error.py`` bounds that difference at the sensor's corner, where
distortion is largest. A marker is looked for where the pinhole image puts it; one whose
measured pixel falls off the sensor is missing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.camera_model import CameraModel
from capture_bench.sensing.pixels import pixel_of, pixel_to_image_plane, principal_point
from capture_bench.sim.rotations import axis_angle_to_matrix

FloatArray = NDArray[np.float64]

#: The calibration error's random stream: ``default_rng([key, CALIBRATION_STREAM])`` with ``key``
#: the episode's noise key (`capture_bench.sensing.rendered_sensor.SceneEpisode`), so the error
#: is a function of the episode's seed and draws nothing from the episode's generator.
CALIBRATION_STREAM = 0xCA11B
#: Newton steps of `Distortion.remove` at most (4 for the shipped lens over the sensor).
UNDISTORT_STEPS = 30
#: `Distortion.remove` solves this many points or fewer one by one in Python floats.
SMALL_BATCH = 16


@dataclass(frozen=True)
class Distortion:
    """Brown-Conrady distortion coefficients, OpenCV's convention (module docstring).

    Attributes:
        k1, k2: radial coefficients (of r^2 and r^4), dimensionless.
        p1, p2: tangential coefficients, dimensionless.
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    @property
    def zero(self) -> bool:
        """Whether every coefficient is 0 (no distortion)."""
        return self.k1 == self.k2 == self.p1 == self.p2 == 0.0

    def apply(self, normalised: ArrayLike) -> FloatArray:
        """Undistorted normalised coordinates ``(x', y')`` (N, 2) -> distorted ``(x'', y'')``."""
        n = np.asarray(normalised, dtype=float)
        x, y = n[:, 0], n[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + self.k2 * r2)
        xy = 2.0 * x * y
        return np.column_stack(
            [
                x * radial + self.p1 * xy + self.p2 * (r2 + 2.0 * x * x),
                y * radial + self.p1 * (r2 + 2.0 * y * y) + self.p2 * xy,
            ]
        )

    def remove(self, distorted: ArrayLike) -> FloatArray:
        """Distorted normalised coordinates (N, 2) -> undistorted: `apply`'s inverse by Newton's
        method from the distorted point (`_newton_step`), until no coordinate moves more than
        1e-15 (at most `UNDISTORT_STEPS` steps; NaN rows stay NaN). Up to `SMALL_BATCH` points
        are solved one by one in Python floats (a frame's markers: faster than array
        arithmetic), more as arrays; each point takes the same steps either way, to the bit."""
        target = np.asarray(distorted, dtype=float)
        if self.zero:
            return target.copy()
        if target.shape[0] <= SMALL_BATCH:
            rows = [self._remove_one(tx, ty) for tx, ty in target.tolist()]
            return np.array(rows, dtype=float).reshape(target.shape)
        tx, ty = target[:, 0], target[:, 1]
        x, y = tx.copy(), ty.copy()
        moving = np.ones(tx.shape, dtype=bool)  # the points still taking steps
        for _ in range(UNDISTORT_STEPS):
            with np.errstate(divide="ignore", invalid="ignore"):
                dx, dy = self._newton_step(x, y, tx, ty)
            singular = ~np.isfinite(dx) | ~np.isfinite(dy)
            x = np.where(moving, np.where(singular, np.nan, x - dx), x)
            y = np.where(moving, np.where(singular, np.nan, y - dy), y)
            moving &= (np.abs(dx) > 1e-15) | (np.abs(dy) > 1e-15)  # NaN compares False
            if not moving.any():
                break
        return np.column_stack([x, y])

    def _remove_one(self, tx: float, ty: float) -> tuple[float, float]:
        """`remove` of one point, in Python floats (NaN where the Jacobian is singular)."""
        x, y = tx, ty
        for _ in range(UNDISTORT_STEPS):
            try:
                dx, dy = self._newton_step(x, y, tx, ty)
            except ZeroDivisionError:  # a singular Jacobian: past the lens's fold, no inverse
                return math.nan, math.nan
            x -= dx
            y -= dy
            if not (abs(dx) > 1e-15 or abs(dy) > 1e-15):
                break  # NaN compares False
        return x, y

    def _newton_step(self, x: Any, y: Any, tx: Any, ty: Any) -> tuple[Any, Any]:
        """Newton's step toward ``apply(x, y) = (tx, ty)`` (floats or arrays alike): the
        residual times the inverse of `apply`'s 2 x 2 Jacobian, in closed form."""
        k1, k2, p1, p2 = self.k1, self.k2, self.p1, self.p2
        x2, y2, xy = x * x, y * y, x * y
        r2 = x2 + y2
        radial = 1.0 + r2 * (k1 + k2 * r2)
        slope = 2.0 * (k1 + 2.0 * k2 * r2)  # 2 d radial / d r^2
        fx = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2) - tx
        fy = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy - ty
        a = radial + x2 * slope + 2.0 * p1 * y + 6.0 * p2 * x  # d x'' / d x'
        b = radial + y2 * slope + 6.0 * p1 * y + 2.0 * p2 * x  # d y'' / d y'
        c = xy * slope + 2.0 * p1 * x + 2.0 * p2 * y  # d x'' / d y' = d y'' / d x'
        det = a * b - c * c
        return (b * fx - c * fy) / det, (a * fy - c * fx) / det


@dataclass(frozen=True)
class TrueCamera:
    """The camera that takes an episode's images, and the nominal calibration that reads them.

    Attributes:
        model: the true pinhole: its pose and f (what is rendered).
        principal_offset: true principal point minus the nominal one (the image centre),
            pixels ``(du, dv)``, shape (2,).
        distortion: the true lens's coefficients.
        nominal: the calibrated camera the estimator knows.
        nominal_distortion: the calibrated coefficients.
    """

    model: CameraModel
    principal_offset: FloatArray
    distortion: Distortion
    nominal: CameraModel
    nominal_distortion: Distortion

    def measured_pixels(self, pinhole_pixels: ArrayLike) -> FloatArray:
        """Pixels of the true pinhole (`model`, principal point at the image centre) (N, 2) ->
        what the true lens and sensor record: distorted with the true coefficients about the
        image centre, then moved by `principal_offset`."""
        p = np.asarray(pinhole_pixels, dtype=float)
        centre = principal_point(self.model)
        scale = self.model.focal_length / self.model.pixel_pitch
        distorted = self.distortion.apply((p - centre) / scale)
        return centre + self.principal_offset + scale * distorted

    def on_sensor(self, pixels: ArrayLike) -> NDArray[np.bool_]:
        """(N,) True where pixels ``[u, v]`` (N, 2) fall on the sensor, edges included
        (``[-0.5, width - 0.5] x [-0.5, height - 0.5]``); False for NaN."""
        p = np.asarray(pixels, dtype=float)
        width, height = self.model.resolution
        with np.errstate(invalid="ignore"):
            inside = (p >= -0.5) & (p <= np.array([width - 0.5, height - 0.5]))
        return np.all(inside, axis=1)

    def observe(self, points_cam: ArrayLike, noise: ArrayLike) -> tuple[FloatArray, NDArray]:
        """The analytic camera's frame through this camera: points in the true camera's frame
        (metres, (N, 3), beyond its lens) projected by its pinhole and lens
        (`measured_pixels`), ``noise`` (image-plane metres, (N, 2)) added to them as pixels,
        and read with the nominal calibration (`calibrated_points`).

        Returns:
            Image-plane points of the nominal camera, metres, (N, 2), and (N,) whether each
            noiseless pixel falls on the sensor (`on_sensor`).
        """
        with np.errstate(divide="ignore", invalid="ignore"):
            pixels = self.measured_pixels(pixel_of(points_cam, self.model))
            noisy = pixels + np.asarray(noise, dtype=float) / self.model.pixel_pitch
            return self.calibrated_points(noisy), self.on_sensor(pixels)

    def calibrated_points(self, pixels: ArrayLike) -> FloatArray:
        """Measured pixels (N, 2) -> eq. 2's image-plane points of the nominal camera (metres,
        (N, 2)): undistorted with the nominal coefficients about the nominal principal point
        and f, as a calibrated system reads them."""
        p = np.asarray(pixels, dtype=float)
        centre = principal_point(self.nominal)
        scale = self.nominal.focal_length / self.nominal.pixel_pitch
        undistorted = self.nominal_distortion.remove((p - centre) / scale)
        return pixel_to_image_plane(centre + scale * undistorted, self.nominal)


@dataclass(frozen=True)
class CalibrationSpread:
    """The nominal lens and the spread of the per-episode calibration error (0: none).

    Attributes:
        distortion: the nominal (calibrated) distortion coefficients; the true lens has them but
            for k1's error.
        focal: standard deviation of ``f_true / f - 1``, dimensionless.
        principal: standard deviation of the principal point's error on each axis, pixels.
        k1: standard deviation of the true k1 minus the nominal one, dimensionless.
        rotation: standard deviation of the orientation's error about each camera axis, rad.
        position: standard deviation of the position's error along each global axis, metres.
    """

    distortion: Distortion = Distortion()
    focal: float = 0.0
    principal: float = 0.0
    k1: float = 0.0
    rotation: float = 0.0
    position: float = 0.0

    @property
    def active(self) -> bool:
        """Whether the true camera can differ from a plain pinhole at the nominal calibration."""
        spread = (self.focal, self.principal, self.k1, self.rotation, self.position)
        return not self.distortion.zero or any(s != 0.0 for s in spread)

    def draw(self, key: int, nominal: CameraModel) -> TrueCamera:
        """The true camera of the episode whose noise key is ``key``: ten standard normals from
        ``default_rng([key, CALIBRATION_STREAM])``, always in this order whatever is 0: focal
        length, principal point (u, v), k1, rotation vector (camera x, y, z), position (global
        x, y, z). The rotation is ``R_true = R_gc exp([w]_x)``, w in the camera frame."""
        z = np.random.default_rng([int(key) % 2**64, CALIBRATION_STREAM]).standard_normal(10)
        w = self.rotation * z[4:7]
        angle = float(np.linalg.norm(w))
        turn = axis_angle_to_matrix(w, angle) if angle > 0.0 else np.eye(3)
        model = CameraModel(
            position=nominal.position + self.position * z[7:10],
            rotation=nominal.rotation @ turn,
            focal_length=nominal.focal_length * (1.0 + self.focal * z[0]),
            pixel_pitch=nominal.pixel_pitch,
            resolution=nominal.resolution,
        )
        d = self.distortion
        lens = Distortion(d.k1 + self.k1 * z[3], d.k2, d.p1, d.p2)
        return TrueCamera(model, self.principal * z[1:3], lens, nominal, d)
