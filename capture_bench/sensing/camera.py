"""The eye-to-hand camera: pinhole projection (paper eq. 2), pixel noise, drop-out and latency.

Frames (see ``docs/architecture.md``):

* The camera frame's origin is the centre of the image plane; its y-axis points toward the scene
  and the lens sits at ``y = f``. ``R_gc`` (3, 3) has the camera axes as columns, in global
  coordinates: ``p_global = position + R_gc @ p_camera``.
* Image-plane coordinates are metres ``(x_m, z_m)`` (divide by the pixel pitch for pixels); x_m
  runs along the camera x-axis (sensor width), z_m along the camera z-axis (sensor height).

`CameraModel` is the pure geometry; `Camera` is the sensor that adds noise, drop-out
and latency, drawing every random number from the generator it is given. An episode's state (the
latency pipeline, the capture count, the latest capture's flags) is a `CameraEpisode` the caller
holds and passes to each capture, so one camera serves any number of episodes.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sim.rotations import look_at

FloatArray = NDArray[np.float64]

# A point must lie at least this far beyond the lens (y_C - f, metres) to count as in front of it.
LENS_MARGIN = 1e-3
#: Standard deviation of the rendered camera's marker centroids about eq. 2 with no blur, noise
#: or exposure, pixels per axis: the per-axis RMS of detected minus eq. 2 for the default
#: rendering over 200 unoccluded poses 0.8-2 m from the lens,
#: ``taskset -c 0 python benchmarks/bench_rendered_sensor.py --poses 200``. The EKF's measurement
#: noise in rendered mode follows the camera's settings instead
#: (`capture_bench.sensing.detection_noise`).
RENDERED_DETECTION_SIGMA_PX = 0.043


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


@dataclass
class Frame:
    """One delivered image.

    Attributes:
        image_points: noisy image-plane coordinates ``[x_m, z_m]`` of the feature points, metres,
            shape (N, 2), in the order of the feature points.
        visible: always True for a delivered frame (a frame is only made when every point is seen).
        capture_index: index of the capture call that took the image (0-based since ``reset``);
            with latency it is older than the call that delivered it.
    """

    image_points: FloatArray
    visible: bool = True
    capture_index: int = 0


@dataclass(slots=True)
class CameraEpisode:
    """One episode's state of a `Camera`: what its captures change. `Camera.reset` makes one;
    each `Camera.capture` takes it and updates it.

    Attributes:
        pipeline: the frames taken and not yet delivered (latency), oldest first.
        count: captures taken in the episode.
        last_visible: whether every point was in front of the lens and on the sensor at the latest
            capture (the current one, not the delayed frame delivered). Lets the caller tell
            "not visible" from "dropped".
        last_dropped: whether the latest capture was lost to drop-out.
    """

    pipeline: deque[Frame | None] = field(default_factory=deque)
    count: int = 0
    last_visible: bool = True
    last_dropped: bool = False


class Camera:
    """The sensor: eq. 2 projection plus Gaussian pixel noise, random drop-out and latency.

    The camera holds its settings only; an episode's state is the `CameraEpisode` passed to
    `capture`.

    Args:
        model: the camera geometry.
        noise_px: standard deviation of the image noise, pixels (0 for a perfect camera).
        dropout: probability in [0, 1) that a frame is lost.
        latency_frames: a frame taken at capture k is delivered by capture k + latency_frames.
    """

    def __init__(
        self,
        model: CameraModel,
        noise_px: float = 1.0,
        dropout: float = 0.0,
        latency_frames: int = 0,
    ) -> None:
        if noise_px < 0:
            raise ValueError(f"noise_px must be >= 0, got {noise_px}")
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        if latency_frames < 0 or int(latency_frames) != latency_frames:
            raise ValueError(f"latency_frames must be an integer >= 0, got {latency_frames}")
        self.model = model
        self.noise_px = float(noise_px)
        self.dropout = float(dropout)
        self.latency_frames = int(latency_frames)

    @property
    def noise_std(self) -> float:
        """Standard deviation of the image noise on the image plane, metres."""
        return self.noise_px * self.model.pixel_pitch

    def reset(self) -> CameraEpisode:
        """A new episode's state: an empty latency pipeline, no capture yet (no random draw)."""
        return CameraEpisode()

    def capture(
        self, state: CameraEpisode, points_global: ArrayLike, rng: np.random.Generator
    ) -> Frame | None:
        """Take one image of the feature points in the episode ``state`` and return the frame due
        now, if any.

        Random numbers are drawn in a fixed order on every call, whatever happens to the frame:
        one uniform (drop-out), then N x 2 standard normals (noise). A seeded generator therefore
        gives identical results, and visibility never shifts the random stream.

        Args:
            state: the episode's state (`reset`), updated: the frame joins its pipeline, the
                count and the latest capture's flags are this capture's.
            points_global: feature points in the global frame, metres, shape (N, 3).
            rng: the generator for drop-out and noise.

        Returns:
            The frame captured ``latency_frames`` calls ago (None while the pipeline fills), or
            None when that frame was dropped or not every point was visible.
        """
        model = self.model
        p_cam = model.to_camera(np.atleast_2d(points_global))
        lost = rng.random() < self.dropout
        noise = rng.standard_normal((p_cam.shape[0], 2)) * self.noise_std
        # model.visible(p_cam).all(), without the work for a single point behind the lens.
        visible = bool((p_cam[:, 1] > model.focal_length + LENS_MARGIN).all())
        frame = None
        if visible:
            image = model.project(p_cam)
            visible = bool((np.abs(image) <= model._half_extent).all())  # on_sensor
            if visible and not lost:
                frame = Frame(image + noise, True, state.count)
        state.last_visible = visible
        state.last_dropped = bool(lost)
        state.count += 1
        pipeline = state.pipeline
        pipeline.append(frame)
        if len(pipeline) > self.latency_frames:
            return pipeline.popleft()
        return None

    def capture_sequence(
        self, points_global: FloatArray, rng: np.random.Generator
    ) -> tuple[FloatArray, NDArray[np.bool_]]:
        """`capture` called once for each of T instants of a new episode (`reset`): the same
        random draws in the same order, the geometry vectorised over the instants.

        Args:
            points_global: feature points at each instant, global, metres, shape (T, N, 3).
            rng: the generator for drop-out and noise.

        Returns:
            ``images`` (T, N, 2): the frame delivered at each call, metres, NaN where
            `capture` returns None; ``visible`` (T,): `CameraEpisode.last_visible` after each
            call.
        """
        model = self.model
        p = np.asarray(points_global, dtype=float)
        n_t, n_points = p.shape[0], p.shape[1]
        lost = np.empty(n_t, dtype=bool)
        noise = np.empty((n_t, n_points, 2))
        random, normal = rng.random, rng.standard_normal
        for k in range(n_t):  # capture()'s draws: one uniform, then N x 2 standard normals
            lost[k] = random() < self.dropout
            normal(out=noise[k])
        noise *= self.noise_std
        p_cam = model.to_camera(p)  # one (N, 3) product per instant, as capture() makes it
        front = (p_cam[:, :, 1] > model.focal_length + LENS_MARGIN).all(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            image = model.project(p_cam.reshape(-1, 3)).reshape(n_t, n_points, 2)
            on_sensor = (np.abs(image) <= model._half_extent).all(axis=(1, 2))
            visible: NDArray[np.bool_] = np.asarray(front & on_sensor, dtype=bool)
        images = np.where((visible & ~lost)[:, None, None], image + noise, np.nan)
        latency = self.latency_frames
        if latency:  # the frame taken at call k is delivered by call k + latency
            images = np.concatenate([np.full((min(latency, n_t), n_points, 2), np.nan), images])
            images = images[:n_t]
        return images, visible
