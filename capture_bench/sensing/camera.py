"""The eye-to-hand camera: pinhole projection (paper eq. 2), pixel noise, drop-out and latency;
optionally a lens and a calibration error (`capture_bench.sensing.calibration`).

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
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.camera_model import LENS_MARGIN, CameraModel

if TYPE_CHECKING:
    from capture_bench.sensing.calibration import CalibrationSpread, TrueCamera

FloatArray = NDArray[np.float64]

#: Standard deviation of the rendered camera's marker centroids about eq. 2 with no blur, noise
#: or exposure, pixels per axis: the per-axis RMS of detected minus eq. 2 for the default
#: rendering over 200 unoccluded poses 0.8-2 m from the lens,
#: ``taskset -c 0 python benchmarks/bench_rendered_sensor.py --poses 200``. The EKF's measurement
#: noise in rendered mode follows the camera's settings instead
#: (`capture_bench.sensing.detection_noise`).
RENDERED_DETECTION_SIGMA_PX = 0.043


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
        lens: the episode's true camera (`Camera.reset` with a calibration); None: `model`.
    """

    pipeline: deque[Frame | None] = field(default_factory=deque)
    count: int = 0
    last_visible: bool = True
    last_dropped: bool = False
    lens: TrueCamera | None = None


class Camera:
    """The sensor: eq. 2 projection plus Gaussian pixel noise, random drop-out and latency.

    The camera holds its settings only; an episode's state is the `CameraEpisode` passed to
    `capture`.

    Args:
        model: the camera geometry.
        noise_px: standard deviation of the image noise, pixels (0 for a perfect camera).
        dropout: probability in [0, 1) that a frame is lost.
        latency_frames: a frame taken at capture k is delivered by capture k + latency_frames.
        calibration: the nominal lens and the spread of each episode's calibration error
            (`capture_bench.sensing.calibration`): the points are projected by the episode's
            true camera, the noise added to its pixels and the result read with the nominal
            calibration; None (or one that is all 0): eq. 2 at ``model``, exactly.
    """

    def __init__(
        self,
        model: CameraModel,
        noise_px: float = 1.0,
        dropout: float = 0.0,
        latency_frames: int = 0,
        calibration: CalibrationSpread | None = None,
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
        active = calibration is not None and calibration.active
        self.calibration = calibration if active else None

    @property
    def noise_std(self) -> float:
        """Standard deviation of the image noise on the image plane, metres."""
        return self.noise_px * self.model.pixel_pitch

    def reset(self, rng: np.random.Generator | None = None) -> CameraEpisode:
        """A new episode's state: an empty latency pipeline, no capture yet. No random draw,
        but with a `calibration` and ``rng``: the episode's true camera, from one
        ``rng.integers(0, 2**64, dtype=np.uint64)`` (`draw_lens`; without ``rng``: key 0)."""
        return CameraEpisode(lens=self.draw_lens(rng))

    def draw_lens(self, rng: np.random.Generator | None) -> TrueCamera | None:
        """The episode's true camera (`CalibrationSpread.draw` of a key drawn from ``rng``, one
        ``integers`` call; key 0 without ``rng``); None, drawing nothing, without a
        `calibration`."""
        if self.calibration is None:
            return None
        key = 0 if rng is None else int(rng.integers(0, 2**64, dtype=np.uint64))
        return self.calibration.draw(key, self.model)

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
        model = self.model if state.lens is None else state.lens.model
        p_cam = model.to_camera(np.atleast_2d(points_global))
        lost = rng.random() < self.dropout
        noise = rng.standard_normal((p_cam.shape[0], 2)) * self.noise_std
        # model.visible(p_cam).all(), without the work for a single point behind the lens.
        visible = bool((p_cam[:, 1] > model.focal_length + LENS_MARGIN).all())
        frame = None
        if visible and state.lens is not None:
            image, on = state.lens.observe(p_cam, noise)
            visible = bool(on.all())
            if visible and not lost:
                frame = Frame(image, True, state.count)
        elif visible:
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

        With a `calibration`, the episode's true camera is drawn first, as `reset` draws it.
        """
        lens = self.draw_lens(rng)
        model = self.model if lens is None else lens.model
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
            if lens is None:
                image = model.project(p_cam.reshape(-1, 3)).reshape(n_t, n_points, 2)
                on_sensor = (np.abs(image) <= model._half_extent).all(axis=(1, 2))
                image = image + noise
            else:
                flat, on = lens.observe(p_cam.reshape(-1, 3), noise.reshape(-1, 2))
                image = flat.reshape(n_t, n_points, 2)
                on_sensor = on.reshape(n_t, n_points).all(axis=1)
            visible: NDArray[np.bool_] = np.asarray(front & on_sensor, dtype=bool)
        images = np.where((visible & ~lost)[:, None, None], image, np.nan)
        latency = self.latency_frames
        if latency:  # the frame taken at call k is delivered by call k + latency
            images = np.concatenate([np.full((min(latency, n_t), n_points, 2), np.nan), images])
            images = images[:n_t]
        return images, visible
