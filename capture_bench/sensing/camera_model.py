"""The camera's geometry: the pinhole projection (paper eq. 2) and `CameraModel`, the camera's
pose and intrinsics (frames: `capture_bench.sensing.camera`'s docstring). Pure geometry, no noise:
what the sensors (`capture_bench.sensing.camera`, `capture_bench.sensing.rendered_sensor`) and the
lens (`capture_bench.sensing.calibration`) build on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sim.rotations import look_at

FloatArray = NDArray[np.float64]

# A point must lie at least this far beyond the lens (y_C - f, metres) to count as in front of it.
LENS_MARGIN = 1e-3


def project_points(points_cam: ArrayLike, focal_length: float) -> FloatArray:
    """Pinhole projection, eq. 2: ``x_m = -f x_C / (y_C - f)``, ``z_m = -f z_C / (y_C - f)``.

    Args:
        points_cam: points in the camera frame, metres, shape (N, 3).
        focal_length: f, metres.

    Returns:
        Image-plane coordinates ``[x_m, z_m]``, metres, shape (N, 2). Points at or behind the lens
        give meaningless (possibly infinite) values; test them with `CameraModel.in_front`.
    """
    p = np.asarray(points_cam, dtype=float)
    scale = -focal_length / (p[:, 1] - focal_length)  # eq. 2
    return p[:, 0::2] * scale[:, None]


@dataclass(frozen=True, eq=False)
class CameraModel:
    """Geometry of a camera fixed in the global frame.

    Attributes:
        position: centre of the image plane in the global frame, metres, shape (3,).
        rotation: R_gc, camera axes as columns in global coordinates, shape (3, 3).
        focal_length: f, metres.
        pixel_pitch: size of one pixel on the image plane, metres.
        resolution: (width, height) in pixels; width along camera x, height along camera z.
    """

    position: FloatArray
    rotation: FloatArray
    focal_length: float = 0.008
    pixel_pitch: float = 3.75e-6
    resolution: tuple[int, int] = field(default=(1280, 960))
    _half_extent: FloatArray = field(init=False, repr=False)  # cache of half_extent

    def __post_init__(self) -> None:
        position = np.asarray(self.position, dtype=float).reshape(3)
        rotation = np.asarray(self.rotation, dtype=float).reshape(3, 3)
        if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-9):
            raise ValueError("CameraModel.rotation must be orthonormal (R_gc^T R_gc = I)")
        if self.focal_length <= 0 or self.pixel_pitch <= 0:
            raise ValueError(
                f"focal_length and pixel_pitch must be > 0, got {self.focal_length}, "
                f"{self.pixel_pitch}"
            )
        object.__setattr__(self, "position", position)
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "resolution", (int(self.resolution[0]), int(self.resolution[1])))
        half = 0.5 * self.pixel_pitch * np.array(self.resolution, dtype=float)
        object.__setattr__(self, "_half_extent", half)  # read by on_sensor on every capture

    @classmethod
    def looking_at(cls, position: ArrayLike, target: ArrayLike, **kwargs: object) -> CameraModel:
        """A camera at ``position`` (global, m) whose y-axis points at ``target`` (global, m).

        The camera z-axis is as close to global z as possible (``rotations.look_at``); extra
        keyword arguments (``focal_length``, ``pixel_pitch``, ``resolution``) go to the constructor.
        """
        return cls(
            position=np.asarray(position, dtype=float),
            rotation=look_at(position, target),
            **kwargs,  # type: ignore[arg-type]
        )

    @property
    def half_extent(self) -> FloatArray:
        """Half width and half height of the sensor on the image plane, metres, shape (2,)."""
        return self._half_extent.copy()

    @property
    def half_fov(self) -> tuple[float, float]:
        """Half field of view (horizontal, vertical), radians: ``atan(half_extent / f)``."""
        h = np.arctan(self.half_extent / self.focal_length)
        return float(h[0]), float(h[1])

    def to_camera(self, points_global: ArrayLike) -> FloatArray:
        """Global points (N, 3) -> camera frame (N, 3): ``R_gc^T (p - position)``, metres."""
        return (np.asarray(points_global, dtype=float) - self.position) @ self.rotation

    def to_global(self, points_cam: ArrayLike) -> FloatArray:
        """Camera-frame points (N, 3) -> global (N, 3): ``position + R_gc p`` (eq. 11), metres."""
        return np.asarray(points_cam, dtype=float) @ self.rotation.T + self.position

    def vector_to_global(self, v_cam: ArrayLike) -> FloatArray:
        """Rotate camera-frame vectors (..., 3) to global (eq. 12 with T-dot = 0): ``R_gc v``."""
        return np.asarray(v_cam, dtype=float) @ self.rotation.T

    def project(self, points_cam: ArrayLike) -> FloatArray:
        """Eq. 2 for camera-frame points (N, 3) -> image plane ``[x_m, z_m]`` (N, 2), metres."""
        return project_points(points_cam, self.focal_length)

    def in_front(self, points_cam: ArrayLike) -> NDArray[np.bool_]:
        """(N,) True where a camera-frame point lies beyond the lens: ``y_C > f + LENS_MARGIN``."""
        p = np.asarray(points_cam, dtype=float)
        return p[:, 1] > self.focal_length + LENS_MARGIN

    def on_sensor(self, image_points: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_]:
        """(N,) True where image points (N, 2, metres) fall on the sensor (edges included), or,
        with ``margin`` > 0, inside its central ``1 - margin`` fraction of width and height."""
        m = np.abs(np.asarray(image_points, dtype=float))
        return np.all(m <= (1.0 - margin) * self._half_extent, axis=1)

    def visible(self, points_cam: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_]:
        """(N,) True where a camera-frame point is in front of the lens and lands on the sensor
        (within ``margin``, see `on_sensor`)."""
        p = np.asarray(points_cam, dtype=float)
        front = self.in_front(p)
        with np.errstate(divide="ignore", invalid="ignore"):
            on = self.on_sensor(np.where(front[:, None], self.project(p), np.inf), margin)
        return front & on
