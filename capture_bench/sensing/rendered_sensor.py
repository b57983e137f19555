"""The rendered camera as a sensor: pybullet draws what the eye-to-hand camera sees, the colour-blob
detector finds the markers, and the frame carries their eq. 2 image-plane points.

`RenderedCamera` is a sibling of `Camera`: the same
drop-out and latency, frames usable wherever a ``Frame`` is, but points measured in an image, so
a marker hidden (by the arm, another marker, the block), too small or cut by the sensor's edge is
a NaN row with the detector's reason, never a guess.

**Windows (the fast path).** Each marker's window bounds its sphere's exact image (the disc of the
ellipse's semi-major axis, `sphere_image`) at every sub-frame
instant, plus ``WINDOW_MARGIN_PX`` and the point-spread function's reach R (`psf_radius`), cut
to the sensor; each window is rendered R pixels wider on every side (cut to the sensor),
blurred, and cut back. With motion blur the windows are pasted on one black image over their
bounding box, and every marker is looked for in it. A marker not wholly beyond the near plane
at every instant, or whose window misses the
sensor, is missing (``no_blob``) without rendering, in both paths. Before each window, the shapes
whose bounding spheres cannot reach it are hidden (`window_keeps`; alpha 0, which
TinyRenderer skips): the pixels stay the same and a capture costs less.
``benchmarks/bench_rendered_sensor.py`` times a capture and its parts (the table "The rendered
camera" of ``docs/speed.md``): rendering the windows is most of it (a fixed cost per
``getCameraImage`` call before any pixel, then the pixels of marker or arm shaded), then
detection, then windows, culling, exact-float re-detections and bookkeeping; the full frame
costs many times a windowed capture. One window over all four markers takes longer to render
(the arm behind them is costly to shade); merging overlapping windows measured no gain.

**Windowed = full frame** (``windowed=False``), because:

* every pixel of marker i's colour lies in marker i's window: the sphere mesh lies inside the
  sphere (every marker pixel's centre >= 0.04 px inside the semi-major disc, measured 0.3-4 m),
  no other surface has a marker's hue and saturation (`capture_bench.sim.markers`), and a
  mean of colours, over sub-frames or under the point-spread function, can only fall in a band
  where some marker's colour reaches (a green marker over the blue arm makes cyan): within R of
  where a marker passed, which the windows cover, all looked in for every colour under motion
  blur (outside them the black canvas, like the full frame's other surfaces, is in no band);
* the blurred pixels of a window are the full frame's: the kernel (`psf_kernel`) is cut at R =
  ``ceil(PSF_TRUNCATE psf_sigma)`` pixels, so a blurred pixel depends only on the pixels within
  R of it, all rendered in the grown window; where the window meets the sensor's edge both
  mirror the image about that edge (`psf_blur`); OpenCV's separable filter gives each pixel the
  same float from either (random windows against a full-frame image: every pixel equal);
* the detector adds the window's origin to a crop-relative centroid before the crop's offset,
  which rounds like the full frame's single sum only when the origin is 0 or in the centroid's
  binade ``[2^k, 2^(k+1))``; otherwise (`exact_origin`, ~20 % of markers, a small part of a
  capture's time) the marker is detected again from the window cut at ``2^k`` or padded with
  black to 0.

No window rule equalises TinyRenderer's float32 rasterisation through each window's own frustum:
a pixel centre on a triangle's edge to float32 precision may be drawn in one and not the other.
Measured over 2800 markers (0.6-2 m, the arm at home or at random joint angles): 6 had one edge
pixel more or less (centroid <= 0.028 px off); status and found mask never differed; every other
centroid was the same float. Image noise of 8 grey levels speckles the arm's shaded blue into the
cyan band (~80 single pixels a full frame, never 4 together in 10 frames; none at 4 grey levels):
speckle outside the windows widens the full frame's crop or joins a missing marker's blob there.
Over 240 markers at 8 grey levels, 7 centroids differed in their last bit (1e-13 px) and 2
missing markers' areas (one ``too_small`` there, ``no_blob`` here).

**Image noise**: Gaussian, ``image_noise`` grey levels, on every RGB channel, then rounded and
clipped to uint8; the value at channel c of pixel (u, v) of frame ``frame_index`` is a pure
function of ``(key, frame_index, (v * width + u) * 3 + c)`` (`pixel_noise`), so a window's
noise is the full frame's. `RenderedCamera.reset` draws the episode's key (kept in its
`SceneEpisode`); `capture` draws only the drop-out uniform, whatever the geometry.

**Optics blur**: the mean image convolved with a Gaussian point-spread function of standard
deviation ``psf_sigma`` pixels (`psf_blur`), before the noise. It is the lens (diffraction,
defocus) and the pixel's own area, which TinyRenderer, sampling one point a pixel, leaves out.
Up to ~0.6 px it changes a centroid by little; from 0.65 px the saturation threshold eats more of
a marker's shaded limb than of its lit side, and the centroid moves toward the light
(`capture_bench.sensing.detection_noise`).

**Lens and calibration error** (`capture_bench.sensing.calibration`): with a
`CalibrationSpread` whose distortion or spread is not 0, `RenderedCamera.reset` also draws the
episode's true camera from its noise key (`CalibrationSpread.draw`, a stream of its own: nothing
more is drawn from the episode's generator). Its pinhole (pose and f) is rendered and detected;
each found centroid is distorted by the true lens and moved by the principal point's error
(`TrueCamera.measured_pixels`; one falling off the sensor is ``at_border``), then read with the
nominal calibration (`TrueCamera.calibrated_points`) into the frame's image-plane points. Without
one, every frame is what it was without these keys, bit for bit.

**Motion blur**: the mean of ``blur_subframes`` renders over ``[t - exposure_s, t]``, noise added
after; when no marker centre's eq. 2 pixel moves ``STILL_EXPOSURE_PX`` (0.5 px) over the
exposure, one render at its middle ``t - exposure_s / 2`` (`RenderedCamera.instants`): the
binary centroid of a smear shorter than half a pixel is the mean position, which the middle
render gives at the cost of one. Otherwise the blob is where the marker stayed long enough to
keep its saturation (>= 3 of 4 sub-frames over white), so its centroid is the mean position,
behind eq. 2 at t by half the exposure's motion: 0.48 px RMS per axis at 20 ms and 0.05 m/s.
A smear over ~half the marker's image radius fails the fill test (``partial``): at 1.2 m and
20 ms, found at 0.2 m/s (7 px), partial at 0.3 m/s (10.7 px).

**Light**: ``light_direction`` is where the light comes from (pybullet's ``lightDirection``,
`Lighting`'s source); ``light_intensity`` scales the
diffuse coefficient (0.4), the ambient one stays 0.6. The detector thresholds hue and saturation,
which shading keeps, and value, which ambient light alone keeps >= 0.6 x 0.8 x 255 = 122 grey
levels on every marker. Measured: all markers of 200 unoccluded poses found, with the same error,
at intensity 1, 0.3 and 0 and lit from +x, -x, +z or behind the target; detection would start
losing markers only with an ambient coefficient below ~0.19 (V < 39 on an unlit side).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench._quiet import quiet_c_output
from capture_bench.sensing.calibration import CalibrationSpread, TrueCamera
from capture_bench.sensing.camera import RENDERED_DETECTION_SIGMA_PX, CameraModel, Frame
from capture_bench.sensing.detector import (
    AT_BORDER,
    FOUND,
    MARKER_BANDS,
    NO_BLOB,
    Detections,
    detect_markers,
)
from capture_bench.sensing.pixels import (
    pixel_of,
    pixel_to_image_plane,
    principal_point,
    sphere_image,
)
from capture_bench.sensing.render_camera import (
    NEAR_PLANE,
    Lighting,
    Window,
    check_window,
    render_frame,
)
from capture_bench.sim.markers import BLOCK_COLOUR, MARKER_COLOURS, MARKER_RADIUS, block_extent
from capture_bench.sim.world import World

with quiet_c_output():  # pybullet prints its build time on import
    import pybullet

FloatArray = NDArray[np.float64]
PoseAt = Callable[[float], tuple[FloatArray, FloatArray]]  # t -> (capture point (3,), R_gt (3, 3))
ThetaAt = Callable[[float], FloatArray]  # t -> joint angles, rad, (3,)
Scene = tuple[FloatArray, FloatArray, FloatArray, FloatArray]  # markers (N, 3), theta, p, R_gt

# Detection error, pixels (measured: sensing.camera.RENDERED_DETECTION_SIGMA_PX's comment).
DETECTION_SIGMA_PX = RENDERED_DETECTION_SIGMA_PX
WINDOW_MARGIN_PX = 2  # pixels of clearance around each marker's image, >= 2 (exact_origin)
PSF_TRUNCATE = 4.0  # the point-spread function's kernel reaches this many sigmas, each side
STILL_EXPOSURE_PX = 0.5  # marker images moving less over the exposure: one render, mid-exposure

_GAMMA = 0x9E3779B97F4A7C15  # splitmix64's increment (2^64 / golden ratio)


@dataclass(frozen=True)
class RenderSettings:
    """How the rendered camera draws and reads its images.

    Attributes:
        marker_radius: radius of the sphere markers, metres, > 0.
        target_block: draw the grey block between the markers (it hides markers in about half
            of random orientations); False: the target is its four markers.
        light_direction: where the light comes from, global (unit or not); None: from the lens.
        light_intensity: scale of the diffuse term, >= 0 (0: ambient light only).
        image_noise: sensor noise, standard deviation in grey levels (0-255) per RGB channel.
        exposure_s: motion blur: the image is the mean of ``blur_subframes`` renders at instants
            evenly spaced over ``[t - exposure_s, t]``, seconds, >= 0 (0: one render at t; one
            at mid-exposure where the markers move less than ``STILL_EXPOSURE_PX``:
            `RenderedCamera.instants`).
        blur_subframes: renders averaged when ``exposure_s > 0``, >= 2.
        psf_sigma: optics blur: the image convolved with a Gaussian point-spread function of
            this standard deviation, pixels, >= 0 (0: none), before the sensor noise.
        windowed: render only windows around the markers (the fast path); False: the full frame
            (the reference).
    """

    marker_radius: float = MARKER_RADIUS
    target_block: bool = False
    light_direction: tuple[float, float, float] | None = None
    light_intensity: float = 1.0
    image_noise: float = 0.0
    exposure_s: float = 0.0
    blur_subframes: int = 4
    psf_sigma: float = 0.0
    windowed: bool = True

    def __post_init__(self) -> None:
        checks = {
            "marker_radius": self.marker_radius > 0.0,
            "light_direction": self.light_direction is None
            or (
                np.shape(self.light_direction) == (3,) and np.linalg.norm(self.light_direction) > 0
            ),
            "light_intensity": self.light_intensity >= 0.0,
            "image_noise": self.image_noise >= 0.0,
            "exposure_s": self.exposure_s >= 0.0,
            "blur_subframes": int(self.blur_subframes) == self.blur_subframes >= 2,
            "psf_sigma": self.psf_sigma >= 0.0,
        }
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"RenderSettings.{name} is out of range: {getattr(self, name)!r}")

    def lighting(self) -> Lighting:
        """The `Lighting` these settings mean."""
        source: tuple[float, float, float] | None = None
        if self.light_direction is not None:
            x, y, z = np.asarray(self.light_direction, dtype=float)
            norm = float(np.sqrt(x * x + y * y + z * z))
            source = (float(x) / norm, float(y) / norm, float(z) / norm)
        return Lighting(source=source, diffuse=Lighting().diffuse * self.light_intensity)

    @property
    def psf_radius(self) -> int:
        """How far the point-spread function's kernel reaches from its centre, whole pixels:
        ``ceil(PSF_TRUNCATE psf_sigma)`` (0 without blur)."""
        return math.ceil(PSF_TRUNCATE * self.psf_sigma)

    def instants(self, time: float) -> FloatArray:
        """The sub-frame instants of an image taken at ``time``, seconds, shape (S,)."""
        if self.exposure_s == 0.0:
            return np.array([float(time)])
        return np.linspace(time - self.exposure_s, time, self.blur_subframes)


@dataclass
class RenderedFrame(Frame):
    """A delivered rendered image: a `Frame` whose missing
    markers are NaN rows of ``image_points``.

    Attributes:
        found: (N,) True where the marker was found.
        status: (N,) the detector's ``FOUND`` or reason (``detector.STATUS_NAMES``).
    """

    found: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    status: NDArray[np.int8] = field(default_factory=lambda: np.zeros(0, dtype=np.int8))


@dataclass(slots=True)
class SceneEpisode:
    """One episode's state of a rendered camera: what its captures change and what they read.
    `RenderedCamera.reset` makes one; each capture takes it, so one camera (one pybullet world)
    renders for any number of episodes.

    Attributes:
        noise_key: the episode's image-noise key (`pixel_noise`).
        lens: the episode's true camera (`CalibrationSpread.draw`); None: the nominal pinhole.
        pipeline: the frames taken and not yet delivered (latency), oldest first.
        count: captures taken in the episode.
        last_visible: whether every marker centre was in front of the lens and on the sensor at
            the latest capture (geometry, as `CameraEpisode.last_visible`).
        last_dropped: whether the latest capture was lost to drop-out.
        last_detections: the detector's answer for the latest capture, in the rendered pinhole
            image, before the lens (None when dropped: no image is rendered then).
        target_only: frame index -> the detections of the target alone, for the seed being
            played (`capture_bench.sensing.scene_camera.RenderedSceneCamera` fills and reuses
            it); None: every frame rendered with the arm.
    """

    noise_key: int = 0
    lens: TrueCamera | None = None
    pipeline: deque[RenderedFrame | None] = field(default_factory=deque)
    count: int = 0
    last_visible: bool = True
    last_dropped: bool = False
    last_detections: Detections | None = None
    target_only: dict[int, Detections] | None = None


def _mix64(z: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """splitmix64's finaliser, elementwise (uint64 arithmetic wraps modulo 2^64)."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def pixel_noise(key: int, frame_index: int, window: Window, width: int) -> FloatArray:
    """Standard normals for the pixels of ``window``, each a pure function of its pixel.

    With ``mix`` splitmix64's finaliser and ``G`` its odd increment (arithmetic modulo 2^64),
    the frame's seed is ``s = mix(key + (frame_index + 1) G)`` and channel c of full-frame pixel
    (u, v), counter ``n = (v * width + u) * 3 + c``, hashes to ``h = mix(s + (n + 1) G)``; its
    high and low 32 bits are the uniforms ``a`` in (0, 1] and ``b`` of one Box-Muller normal
    ``sqrt(-2 ln a) cos(2 pi b)`` (|value| <= 6.8), computed in single precision.

    Args:
        key, frame_index: the episode's noise key and the image's index, integers (mod 2^64).
        window: ``(u0, u1, v0, v1)``, full-frame pixels.
        width: the sensor's width, pixels.

    Returns:
        Standard normals, shape ``(v1 - v0, u1 - u0, 3)``.
    """
    return pixel_noises(key, frame_index, [window], width)[0]


def pixel_noises(
    key: int, frame_index: int, windows: Sequence[Window], width: int
) -> list[FloatArray]:
    """`pixel_noise` of several windows of one image, computed together (the same values)."""
    seed = _mix64(np.array([(key + (frame_index + 1) * _GAMMA) % 2**64], dtype=np.uint64))
    counters = [
        (
            (np.arange(v0, v1, dtype=np.uint64) * np.uint64(3 * width))[:, None, None]
            + (np.arange(u0, u1, dtype=np.uint64) * np.uint64(3))[None, :, None]
            + np.arange(1, 4, dtype=np.uint64)
        )
        for u0, u1, v0, v1 in windows
    ]
    h = _mix64(seed + np.concatenate([c.ravel() for c in counters]) * np.uint64(_GAMMA))
    one = np.float32(2.0**-32)  # single precision: a noise value needs no more, and costs less
    a = ((h >> np.uint64(32)).astype(np.float32) + np.float32(0.5)) * one
    b = (h & np.uint64(0xFFFFFFFF)).astype(np.float32) * one
    z = np.sqrt(np.float32(-2.0) * np.log(a)) * np.cos(np.float32(2.0 * np.pi) * b)
    normals = z.astype(float)
    ends = np.cumsum([c.size for c in counters])[:-1]
    return [z.reshape(c.shape) for z, c in zip(np.split(normals, ends), counters)]


def psf_kernel(sigma: float, reach: int) -> FloatArray:
    """The point-spread function's one-dimensional kernel: a Gaussian of standard deviation
    ``sigma`` pixels sampled at ``-reach .. reach`` and normalised to sum 1, shape
    ``(2 reach + 1, 1)`` (the 2-D kernel is its outer product with itself)."""
    return np.asarray(cv2.getGaussianKernel(2 * reach + 1, sigma, cv2.CV_64F), dtype=float)


def psf_blur(image: FloatArray, sigma: float, reach: int) -> FloatArray:
    """``image`` (H, W, C), float, convolved with the point-spread function (`psf_kernel`),
    separably, the image's edges mirrored (``cv2.BORDER_REFLECT_101``): at the sensor's edge,
    the full frame's rule. A pixel farther than ``reach`` from every edge depends only on the
    pixels within ``reach`` of it."""
    kernel = psf_kernel(sigma, reach)
    flat = np.ascontiguousarray(image, dtype=float)
    out = cv2.sepFilter2D(flat, cv2.CV_64F, kernel, kernel, borderType=cv2.BORDER_REFLECT_101)
    return np.asarray(out, dtype=float).reshape(flat.shape)


def grow_window(window: Window, reach: int, model: CameraModel) -> Window:
    """``window`` ``(u0, u1, v0, v1)`` grown by ``reach`` pixels on each side, cut to the
    sensor."""
    u0, u1, v0, v1 = window
    width, height = model.resolution
    return (max(u0 - reach, 0), min(u1 + reach, width), max(v0 - reach, 0), min(v1 + reach, height))


def cut_window(image: NDArray, region: Window, window: Window) -> NDArray:
    """The pixels of ``window`` from ``image``, the pixels of ``region`` (which holds it)."""
    du, dv = window[0] - region[0], window[2] - region[2]
    return image[dv : dv + window[3] - window[2], du : du + window[1] - window[0]]


def marker_windows(
    model: CameraModel, centres_cam: ArrayLike, radius: float, margin: float = WINDOW_MARGIN_PX
) -> list[Window | None]:
    """Each marker's window: the pixels within ``margin`` of its sphere's image (the disc of the
    ellipse's semi-major axis) at any sub-frame instant, cut to the sensor.

    Args:
        model: the camera.
        centres_cam: marker centres, camera frame, metres, at each instant, shape (S, N, 3).
        radius: marker radius, metres.
        margin: clearance, pixels.

    Returns:
        N windows ``(u0, u1, v0, v1)``; None for a marker whose sphere is not wholly beyond the
        near plane at some instant, or whose window misses the sensor.
    """
    c = np.asarray(centres_cam, dtype=float)
    image = sphere_image(c.reshape(-1, 3), radius, model)
    reach = (image.semi_major + margin).reshape(*c.shape[:2], 1)
    centre = image.centre.reshape(*c.shape[:2], 2)
    lo = np.maximum(np.floor(np.min(centre - reach, axis=0)), 0.0)  # (N, 2): u0, v0
    hi = np.minimum(np.ceil(np.max(centre + reach, axis=0)) + 1.0, model.resolution)
    beyond = np.all(c[:, :, 1] - model.focal_length - radius > NEAR_PLANE, axis=0)
    keep = (beyond & np.all(lo < hi, axis=1)).tolist()
    lo_list, hi_list = np.nan_to_num(lo).tolist(), np.nan_to_num(hi).tolist()
    return [
        (int(a[0]), int(b[0]), int(a[1]), int(b[1])) if k else None
        for k, a, b in zip(keep, lo_list, hi_list)
    ]


def on_canvas(
    images: Sequence[NDArray[np.uint8]], windows: Sequence[Window]
) -> tuple[Window, NDArray[np.uint8]]:
    """The windows' images pasted on one black image over their bounding box: ``(box, image)``
    (overlapping windows hold the same pixels)."""
    u0, u1, v0, v1 = zip(*windows)
    box = (min(u0), max(u1), min(v0), max(v1))
    canvas = np.zeros((box[3] - box[2], box[1] - box[0], 3), dtype=np.uint8)
    for (a, b, c, d), image in zip(windows, images):
        canvas[c - box[2] : d - box[2], a - box[0] : b - box[0]] = image
    return box, canvas


def exact_origin(start: int, own_start: int, value: float) -> int | None:
    """Where, on one axis, the detector's image must start for its centroid ``value`` to be the
    full frame's float (module docstring); None when ``start`` already gives it.

    Args:
        start: the image's first pixel on this axis, full frame.
        own_start: the first pixel of the marker's own window (its image starts
            ``WINDOW_MARGIN_PX`` later), or ``start`` when its colour may be anywhere in the image.
        value: the centroid found from ``start``, pixels.

    Returns:
        None if ``start`` is 0 or in the binade of ``value`` (of ``int(value) + 1``, so a value
        a hair below a power of two counts as above it); else that binade's power of two where
        the image may be cut there (``start < 2^k <= own_start + WINDOW_MARGIN_PX - 1``); else
        0 (pad the image to the sensor's edge).
    """
    top = int(value) + 1
    if start == 0 or start.bit_length() == top.bit_length():
        return None
    power = 1 << (top.bit_length() - 1)
    return power if start < power <= own_start + WINDOW_MARGIN_PX - 1 else 0


def _rebase(image: NDArray[np.uint8], old: Sequence[int], new: Sequence[int]) -> NDArray[np.uint8]:
    """A window's image starting at full-frame pixel ``old`` ``(u, v)`` made to start at ``new``:
    cut where ``new`` is later, padded with black where it is earlier."""
    du, dv = old[0] - new[0], old[1] - new[1]
    image = image[max(-dv, 0) :, max(-du, 0) :]
    return np.pad(image, ((max(dv, 0), 0), (max(du, 0), 0), (0, 0)))


def detect_exactly(
    image: NDArray[np.uint8],
    model: CameraModel,
    start: tuple[int, int],
    members: Sequence[int],
    owns: Sequence[tuple[int, int]],
) -> Detections:
    """`detect_markers` on the image of a window starting at
    full-frame pixel ``start`` ``(u0, v0)``, for markers ``members`` (indices of
    ``MARKER_BANDS``), each found centroid found again where `exact_origin` asks (``owns``:
    each member's ``own_start`` on both axes)."""
    part = detect_markers(image, model, start, [MARKER_BANDS[i] for i in members])
    for k, (i, own) in enumerate(zip(members, owns)):
        if part.status[k] != FOUND:
            continue
        moved = [exact_origin(s, o, p) for s, o, p in zip(start, own, part.pixels[k])]
        if moved != [None, None]:
            u, v = (s if m is None else m for s, m in zip(start, moved))
            new = (u, v)
            again = detect_markers(_rebase(image, start, new), model, new, [MARKER_BANDS[i]])
            part.pixels[k], part.areas[k] = again.pixels[0], again.areas[0]
            part.status[k] = again.status[0]
    return part


def measure(lens: TrueCamera, found: Detections) -> Detections:
    """The detections of ``lens``'s pinhole as its sensor records them: each found centroid
    through `TrueCamera.measured_pixels`; one that lands off the sensor is ``AT_BORDER``
    (NaN)."""
    pixels = lens.measured_pixels(found.pixels)
    on = lens.on_sensor(pixels)
    status = np.where(found.found & ~on, np.int8(AT_BORDER), found.status).astype(np.int8)
    pixels[status != FOUND] = np.nan
    return Detections(pixels, found.areas.copy(), status)


def window_keeps(
    model: CameraModel, windows: Sequence[Window], centres_cam: FloatArray, radii: FloatArray
) -> NDArray[np.bool_]:
    """Which spheres (centres in the camera frame, metres, (K, 3); radii (K,)) may show in each
    window: all but those wholly beyond the near plane and wholly outside one of the four
    planes through the lens and the window's outer pixel edges, moved a pixel outwards.

    Returns:
        (W, K) booleans.
    """
    u0, u1, v0, v1 = np.asarray(windows, dtype=float).reshape(-1, 4).T[:, :, None]  # (W, 1)
    cu, cv = principal_point(model)
    x, depth, z = centres_cam[:, 0], centres_cam[:, 1] - model.focal_length, centres_cam[:, 2]
    scale = model.pixel_pitch / model.focal_length
    inside = np.full((len(windows), len(radii)), np.inf)  # signed distance into the frustum, m
    for slope, along, sign in [
        (scale * (u0 - 1.5 - cu), x, 1.0),  # left edge: x / depth >= slope
        (scale * (u1 + 0.5 - cu), x, -1.0),  # right edge
        (scale * (cv - v1 - 0.5), z, 1.0),  # bottom edge: z / depth >= slope
        (scale * (cv - v0 + 1.5), z, -1.0),  # top edge
    ]:
        inside = np.minimum(inside, sign * (along - slope * depth) / np.hypot(1.0, slope))
    return ~((inside < -radii) & (depth - radii > NEAR_PLANE))


class _Culling:
    """Bounding spheres of the visual shapes a window may skip (the arm's moving links, the
    target's markers and block) and their visibility: a hidden shape has alpha 0, which
    TinyRenderer skips, so a window costs less to render and its pixels stay the same. Without
    ``block`` the target's block is hidden for good."""

    def __init__(self, world: World, features: FloatArray, radius: float, block: bool) -> None:
        bullet = world.client
        self._links, self._arm = [0, 1, 2, 3], world.arm
        self._states, self._matrix = bullet.getLinkStates, bullet.getMatrixFromQuaternion
        self._change = bullet.changeVisualShape
        self.rows = [(world.target, -1, i, MARKER_COLOURS[i]) for i in range(len(features))]
        local, radii = [*features], [radius] * len(features)
        if block:
            centre, extent = block_extent(features, radius)
            self.rows.append((world.target, -1, len(features), BLOCK_COLOUR))
            local.append(centre)
            radii.append(float(np.linalg.norm(extent)))
        else:  # create_marked_target adds the block after the markers: never draw it
            invisible = (*BLOCK_COLOUR[:3], 0.0)
            self._change(world.target, -1, shapeIndex=len(features), rgbaColor=invisible)
        self._target_rows = len(self.rows)
        count: dict[int, int] = {}
        for data in bullet.getVisualShapeData(world.arm):
            link, geometry, dims = data[1], data[2], data[3]
            count[link] = count.get(link, -1) + 1
            if link in self._links:  # the fixed base column is always drawn
                self.rows.append((world.arm, link, count[link], data[7]))
                local.append(data[5])
                half = 0.5 * dims[0]  # cylinders and capsules: (length, radius)
                bound = {
                    pybullet.GEOM_SPHERE: dims[0],
                    pybullet.GEOM_CYLINDER: np.hypot(half, dims[1]),
                    pybullet.GEOM_CAPSULE: half + dims[1],
                }
                radii.append(float(bound.get(geometry, np.inf)))  # any other: always drawn
        self._local, self.radii = np.array(local, dtype=float), np.array(radii)
        self._owner = [self._links.index(row[1]) for row in self.rows[self._target_rows :]]
        self._local_target, self._local_arm = np.split(self._local, [self._target_rows])
        self._shown = np.ones(len(self.rows), dtype=bool)

    def centres(self, position: FloatArray, rotation: FloatArray) -> FloatArray:
        """The spheres' centres, global, metres, (K, 3), for the target's pose and the arm's
        joints as set now."""
        states = self._states(self._arm, self._links, computeForwardKinematics=1)
        frames = np.array([self._matrix(state[5]) for state in states]).reshape(-1, 3, 3)
        origins = np.array([state[4] for state in states])
        arm = origins[self._owner] + np.einsum("kij,kj->ki", frames[self._owner], self._local_arm)
        return np.concatenate([position + self._local_target @ rotation.T, arm])

    def show(self, keep: NDArray[np.bool_]) -> None:
        """Draw the shapes where ``keep`` is True, hide the others (changing only what changes)."""
        for j in np.flatnonzero(keep != self._shown).tolist():
            body, link, index, rgba = self.rows[j]
            alpha = 1.0 if keep[j] else 0.0
            self._change(body, link, shapeIndex=index, rgbaColor=(*rgba[:3], alpha))
        self._shown = keep


class RenderedCamera:
    """The sensor: render the scene (windows around the markers, or the full frame), find the
    markers, and deliver their image-plane points with `Camera`'s drop-out and latency.

    It owns a `World` (arm, floor and marked target; with
    ``target_block=False`` the block is drawn with alpha 0, which TinyRenderer skips) and the
    settings; an episode's state is the `SceneEpisode` passed to `capture`.

    Args:
        model: the camera geometry.
        features: the four feature points (marker centres) in the target frame, metres, (4, 3).
        settings: how to render and detect.
        dropout: probability in [0, 1) that a frame is lost.
        latency_frames: a frame taken at capture k is delivered by capture k + latency_frames.
        calibration: the nominal lens and the spread of each episode's calibration error (module
            docstring); None: a pinhole at ``model``, exactly.
    """

    def __init__(
        self,
        model: CameraModel,
        features: ArrayLike,
        settings: RenderSettings | None = None,
        dropout: float = 0.0,
        latency_frames: int = 0,
        calibration: CalibrationSpread | None = None,
    ) -> None:
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        if latency_frames < 0 or int(latency_frames) != latency_frames:
            raise ValueError(f"latency_frames must be an integer >= 0, got {latency_frames}")
        self.model = model
        self.settings = RenderSettings() if settings is None else settings
        self.features = np.array(features, dtype=float)
        if self.features.shape != (len(MARKER_BANDS), 3):
            raise ValueError(f"features must have shape (4, 3), got {self.features.shape}")
        self.dropout = float(dropout)
        self.latency_frames = int(latency_frames)
        active = calibration is not None and calibration.active
        self.calibration = calibration if active else None
        self._lighting = self.settings.lighting()
        self._world = World(self.features, marker_radius=self.settings.marker_radius)
        self._culling = _Culling(
            self._world, self.features, self.settings.marker_radius, self.settings.target_block
        )
        self._last_instants: tuple[PoseAt, float, FloatArray] | None = None

    def reset(self, rng: np.random.Generator | None = None) -> SceneEpisode:
        """A new episode's state: an empty latency pipeline, no capture yet and, given ``rng``,
        the episode's noise key drawn: one ``rng.integers(0, 2**64, dtype=np.uint64)`` (without:
        key 0); with a `calibration`, the episode's true camera drawn from that key."""
        key = 0 if rng is None else int(rng.integers(0, 2**64, dtype=np.uint64))
        spread = self.calibration
        lens = None if spread is None else spread.draw(key, self.model)
        return SceneEpisode(noise_key=key, lens=lens)

    def true_model(self, episode: SceneEpisode | None) -> CameraModel:
        """The pinhole that renders ``episode``'s images: its true camera's, else `model`."""
        if episode is None or episode.lens is None:
            return self.model
        return episode.lens.model

    def capture(
        self,
        state: SceneEpisode,
        pose_at: PoseAt,
        time: float,
        theta_at: ThetaAt,
        rng: np.random.Generator,
        frame_index: int,
    ) -> RenderedFrame | None:
        """Take one image in the episode ``state`` and return the frame due now, if any.

        Draws exactly one uniform from ``rng`` (drop-out), first, whatever happens; a dropped
        image is not rendered.

        Args:
            state: the episode's state (`reset`), updated: the frame joins its pipeline, the
                count, the latest capture's flags and detections are this capture's.
            pose_at: ``pose_at(t)`` -> (capture point, global, metres, (3,); R_gt, (3, 3)); asked
                at the sub-frame instants (only at ``time`` without blur).
            time: the instant the image is taken (its exposure ends), seconds.
            theta_at: ``theta_at(t)`` -> the arm's joint angles, rad, (3,); asked likewise.
            rng: the generator for drop-out.
            frame_index: the image's index for the noise (`pixel_noise`).

        Returns:
            The frame captured ``latency_frames`` calls ago (None while the pipeline fills), or
            None when that frame was dropped or had no marker found.
        """
        lost = bool(rng.random() < self.dropout)
        position, rotation = pose_at(time)
        points = np.asarray(position) + self.features @ np.asarray(rotation).T
        model = self.true_model(state)
        state.last_visible = bool(model.visible(model.to_camera(points)).all())
        state.last_dropped = lost
        state.last_detections = frame = None
        if not lost:
            found = self.detect(pose_at, time, theta_at, frame_index, state)
            state.last_detections = found
            if state.lens is not None:
                found = measure(state.lens, found)
            if found.found.any():
                if state.lens is None:
                    points = pixel_to_image_plane(found.pixels, self.model)
                else:
                    points = state.lens.calibrated_points(found.pixels)
                frame = RenderedFrame(points, True, state.count, found.found, found.status)
        state.count += 1
        pipeline = state.pipeline
        pipeline.append(frame)
        if len(pipeline) > self.latency_frames:
            return pipeline.popleft()
        return None

    def detect(
        self,
        pose_at: PoseAt,
        time: float,
        theta_at: ThetaAt,
        frame_index: int,
        episode: SceneEpisode | None = None,
    ) -> Detections:
        """Render the image taken at ``time`` and find the markers in it (no drop-out, no
        latency): windows or the full frame, as ``settings.windowed`` says (module docstring);
        the image noise of ``episode``'s key (key 0 without one), through its true pinhole
        (`true_model`): pinhole pixels, before its lens."""
        key = 0 if episode is None else episode.noise_key
        model = self.true_model(episode)
        scenes = self._scenes(pose_at, time, theta_at)
        centres = np.stack([model.to_camera(scene[0]) for scene in scenes])
        margin = WINDOW_MARGIN_PX + self.settings.psf_radius
        windows = marker_windows(model, centres, self.settings.marker_radius, margin)
        n = len(windows)
        out = Detections(
            np.full((n, 2), np.nan), np.zeros(n, np.int64), np.full(n, NO_BLOB, np.int8)
        )
        looked = [i for i, w in enumerate(windows) if w is not None]
        if not self.settings.windowed:
            image = self._images(scenes, [None], frame_index, key, model)[0]
            whole = detect_markers(image, model)
            results = [(looked, whole.pixels[looked], whole.areas[looked], whole.status[looked])]
        else:
            own = {i: (w[0], w[2]) for i, w in enumerate(windows) if w is not None}
            jobs = [(w, [i]) for i, w in enumerate(windows) if w is not None]
            images = self._images(scenes, [w for w, _ in jobs], frame_index, key, model)
            if len(scenes) > 1 and looked:  # motion blur: every colour looked for in every window
                box, canvas = on_canvas(images, [w for w, _ in jobs])
                jobs, images = [(box, looked)], [canvas]
                own = dict.fromkeys(looked, (box[0], box[2]))
            results = []
            for (w, members), image in zip(jobs, images):
                owns = [own[i] for i in members]
                part = detect_exactly(image, model, (w[0], w[2]), members, owns)
                results.append((members, part.pixels, part.areas, part.status))
        for members, pixels, areas, status in results:
            out.pixels[members], out.areas[members], out.status[members] = pixels, areas, status
        return out

    def image(
        self,
        pose_at: PoseAt,
        time: float,
        theta_at: ThetaAt,
        frame_index: int,
        window: Window | None = None,
        noise_key: int = 0,
    ) -> NDArray[np.uint8]:
        """What the sensor records at ``time``: RGB, uint8, ``(v1 - v0, u1 - u0, 3)`` for
        ``window`` ``(u0, u1, v0, v1)``, the full frame for None; blurred and noisy as the
        settings say (the noise of ``noise_key``, `SceneEpisode.noise_key`). A window's pixels
        are the full frame's (but for TinyRenderer's float32 edge pixels, module docstring)."""
        return self.images(pose_at, time, theta_at, frame_index, [window], noise_key)[0]

    def images(
        self,
        pose_at: PoseAt,
        time: float,
        theta_at: ThetaAt,
        frame_index: int,
        windows: Sequence[Window | None],
        noise_key: int = 0,
    ) -> list[NDArray[np.uint8]]:
        """`image` of several windows of one image, the scene set once per sub-frame."""
        scenes = self._scenes(pose_at, time, theta_at)
        return self._images(scenes, windows, frame_index, noise_key, self.model)

    def instants(self, pose_at: PoseAt, time: float) -> FloatArray:
        """The sub-frame instants of the image taken at ``time``, seconds: the settings'
        (`RenderSettings.instants`), or, when every marker centre's eq. 2 pixel moves less than
        ``STILL_EXPOSURE_PX`` over the exposure, its middle ``time - exposure_s / 2`` alone."""
        span = self.settings.instants(time)
        if len(span) == 1:
            return span
        last = self._last_instants  # the scene camera asks twice for one image
        if last is not None and last[0] is pose_at and last[1] == time:
            return last[2]
        ends = []
        for t in (span[0], span[-1]):
            position, rotation = (np.asarray(v, dtype=float) for v in pose_at(float(t)))
            ends.append(position + self.features @ rotation.T)
        cam = self.model.to_camera(np.concatenate(ends))
        if self.model.in_front(cam).all():
            start, end = np.split(pixel_of(cam, self.model), 2)
            if np.max(np.hypot(*(end - start).T)) < STILL_EXPOSURE_PX:
                span = np.array([float(time) - 0.5 * self.settings.exposure_s])
        self._last_instants = (pose_at, time, span)
        return span

    def _scenes(self, pose_at: PoseAt, time: float, theta_at: ThetaAt) -> list[Scene]:
        """``(marker centres, global, (N, 3); theta; capture point; R_gt)`` per sub-frame."""
        scenes = []
        for t in self.instants(pose_at, time):
            position, rotation = (np.asarray(v, dtype=float) for v in pose_at(float(t)))
            theta = np.asarray(theta_at(float(t)), dtype=float)
            scenes.append((position + self.features @ rotation.T, theta, position, rotation))
        return scenes

    def _images(
        self,
        scenes: Sequence[Scene],
        windows: Sequence[Window | None],
        frame_index: int,
        noise_key: int,
        model: CameraModel,
    ) -> list[NDArray[np.uint8]]:
        """Render each window of ``model`` (grown by the point-spread function's reach) at each
        sub-frame, average, blur, cut back to the window, add the noise of ``noise_key``, round to
        uint8."""
        full = [check_window(w, model) for w in windows]
        if not full:
            return []
        reach = self.settings.psf_radius
        drawn = [grow_window(w, reach, model) for w in full]
        sums = self._render_sums(scenes, drawn, model)
        noise, sigma = self.settings.image_noise, self.settings.psf_sigma
        if len(scenes) == 1 and noise == 0.0 and sigma == 0.0:
            return [np.asarray(s, dtype=np.uint8) for s in sums]
        width = model.resolution[0]
        normals = pixel_noises(noise_key, frame_index, full, width) if noise > 0.0 else None
        out = []
        for j, (window, region, total) in enumerate(zip(full, drawn, sums)):
            value = np.asarray(total, dtype=float) / len(scenes)
            if sigma > 0.0:
                value = cut_window(psf_blur(value, sigma, reach), region, window)
            if normals is not None:
                value = value + noise * normals[j]
            out.append(np.clip(np.rint(value), 0, 255).astype(np.uint8))
        return out

    def _render_sums(
        self, scenes: Sequence[Scene], windows: Sequence[Window], model: CameraModel
    ) -> list[NDArray[np.uint8] | FloatArray]:
        """Each window of ``model`` rendered at each sub-frame: the image itself (uint8) for one
        sub-frame, else the float sum over them."""
        sums: list[NDArray[np.uint8] | FloatArray] = []
        try:
            for k, (_, theta, position, rotation) in enumerate(scenes):
                self._world.set_joint_positions(theta.tolist())
                self._world.set_target_pose(position, rotation)
                spheres = model.to_camera(self._culling.centres(position, rotation))
                keeps = window_keeps(model, windows, spheres, self._culling.radii)
                for j, window in enumerate(windows):
                    self._culling.show(keeps[j])
                    image = render_frame(self._world.client, model, window, self._lighting)
                    if len(scenes) == 1:
                        sums.append(image)
                    elif k == 0:
                        sums.append(image.astype(float))
                    else:
                        sums[j] += image
        finally:  # leave every shape drawn, for whoever renders the world next
            self._culling.show(np.ones(len(self._culling.radii), dtype=bool))
        return sums

    def close(self) -> None:
        """Release the pybullet client. Safe to call more than once."""
        self._world.close()

    def __enter__(self) -> RenderedCamera:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
