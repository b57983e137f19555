"""Find the four coloured markers in a rendered image: their pixel centroids, or why not.

Per marker colour (`capture_bench.sim.markers.MARKER_COLOURS`):

1. **Threshold in HSV.** A pixel belongs to the marker when its hue is within
   ``HUE_TOLERANCE_DEG`` of the marker's, its saturation is at least ``MIN_SATURATION`` and its
   value at least ``MIN_VALUE``. Ambient and diffuse shading scale a surface's RGB, which leaves
   hue and saturation unchanged, so the threshold holds on the lit and the shaded side alike; the
   greys of the arm, floor, target block and background have saturation <= 0.08 and the arm's
   blue and orange are >= 32 deg of hue from every marker (the table in
   `capture_bench.sim.markers`).
2. **Connected components** (8-connected) of that mask; the largest is the marker.
3. **Centroid**: the mean of the component's pixel coordinates, i.e. its binary image moments
   ``(m10 / m00, m01 / m00)``, in the pixel convention of `capture_bench.sensing.pixels`
   (integers at pixel centres). Binary, not intensity-weighted: shading would pull a weighted
   centroid toward the lit side.

A marker is reported missing (NaN pixels) with the reason in ``status``:

* ``NO_BLOB``: no pixel of its colour;
* ``TOO_SMALL``: the largest blob has fewer than ``min_area`` pixels (``MIN_AREA_PX`` = 4);
* ``AT_BORDER``: the largest blob touches the image's (or the window's) edge, so part of it may
  lie outside and its centroid would be pulled inward; a marker outside the image is missing,
  never clipped to the border;
* ``SPLIT``: a second blob of the same colour has at least ``min_area`` pixels, so something in
  front of the marker cuts it in two and neither part's centroid is the marker's;
* ``PARTIAL`` (only when the camera model is given): the blob fills too little of the ellipse a
  whole sphere would make there (the fill test below), so something in front hides part of it.

The fill test needs no pose. A sphere's image is an ellipse whose axis ratio is ``cos(alpha)``,
``alpha`` the angle between the ray through its centre and the optical axis (to 1e-5 for
R / D = 0.01), and whose semi-major axis is the radius of the smallest circle enclosing it. So
``fill = area / (pi (r + 0.5)^2 cos(alpha))``, with ``r`` the radius of the smallest circle
enclosing the blob's pixel centres (``+ 0.5``: to the pixels' outer edges), is the share of the
whole marker's image that is seen. An unhidden marker's fill is the share of the ideal ellipse
that TinyRenderer's sphere mesh covers, blurred by the pixel grid by about ``1 / r``: measured
minimum over 100 random poses 0.904, 0.891, 0.870, 0.827, 0.817 at r = 27, 18, 11, 7, 5.5 px
(0.01 m markers 0.8, 1.2, 2, 3, 4 m from the default camera). A marker is ``PARTIAL`` when
``fill < MIN_FILL - FILL_SLACK_PX / r`` (0.867 at 18 px, 0.79 at 5.5 px). This catches the
fragments left of mostly hidden markers (fill 0.1-0.45, centroids 10-15 px off) and partly hidden
markers whose centroid is off by more than ~1.3 px at the default distance; the fill is only good
to a few per cent, so a sliver hidden off the edge of a marker (< ~8 % of it) can pass and bias its
centroid by up to ~1.3 px. Geometry can tell when that may happen
(`capture_bench.sensing.occlusion.hidden_markers`).
"""

from __future__ import annotations

import colorsys
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.pixels import principal_point
from capture_bench.sim.markers import MARKER_COLOURS

MIN_AREA_PX = 4  # pixels: a smaller blob is no measurement
HUE_TOLERANCE_DEG = 15.0  # half width of a marker's hue band, degrees
MIN_SATURATION = 0.5  # in [0, 1]
MIN_VALUE = 0.15  # in [0, 1]: darker pixels have no reliable hue
MIN_FILL = 0.90  # share of a whole marker's image a blob must cover (the fill test) ...
FILL_SLACK_PX = 0.6  # ... less this many pixels over the blob's radius

FOUND, NO_BLOB, TOO_SMALL, AT_BORDER, SPLIT, PARTIAL = 0, 1, 2, 3, 4, 5
STATUS_NAMES = ("found", "no_blob", "too_small", "at_border", "split", "partial")


@dataclass(frozen=True)
class ColourBand:
    """The HSV box a marker's pixels fall in.

    Attributes:
        hue_deg: the marker's hue, degrees in [0, 360).
        tolerance_deg: accepted hue difference either side, degrees.
        min_saturation: lowest accepted saturation, in [0, 1].
        min_value: lowest accepted value (brightness), in [0, 1].
    """

    hue_deg: float
    tolerance_deg: float = HUE_TOLERANCE_DEG
    min_saturation: float = MIN_SATURATION
    min_value: float = MIN_VALUE

    @classmethod
    def of_colour(cls, rgba: Sequence[float]) -> ColourBand:
        """The band around the hue of an RGB(A) colour with components in [0, 1]."""
        hue, _, _ = colorsys.rgb_to_hsv(float(rgba[0]), float(rgba[1]), float(rgba[2]))
        return cls(hue_deg=360.0 * hue)


MARKER_BANDS = tuple(ColourBand.of_colour(colour) for colour in MARKER_COLOURS)


def colour_mask(hsv: NDArray[np.uint8], band: ColourBand) -> NDArray[np.uint8]:
    """Pixels of an OpenCV HSV image (``cv2.COLOR_RGB2HSV``: H in [0, 180) in 2-degree units,
    S and V in [0, 255]; shape (H, W, 3)) inside ``band``: 255 in, 0 out, shape (H, W).
    The hue band wraps around 0 (red)."""
    s_min = int(np.ceil(band.min_saturation * 255.0))
    v_min = int(np.ceil(band.min_value * 255.0))
    lo = int(np.ceil((band.hue_deg - band.tolerance_deg) / 2.0))
    hi = int(np.floor((band.hue_deg + band.tolerance_deg) / 2.0))
    spans = [(lo, hi)]
    if lo < 0:
        spans = [(0, hi), (lo + 180, 179)]
    elif hi > 179:
        spans = [(lo, 179), (0, hi - 180)]
    mask = np.zeros(hsv.shape[:2], dtype=np.uint8)
    for h0, h1 in spans:
        mask |= np.asarray(cv2.inRange(hsv, (h0, s_min, v_min), (h1, 255, 255)), dtype=np.uint8)
    return mask


@dataclass(frozen=True)
class Detections:
    """The detector's answer for one image.

    Attributes:
        pixels: centroids ``[u, v]`` in full-frame pixels (`capture_bench.sensing.pixels`),
            shape (N, 2), NaN where a marker is missing.
        areas: area of each marker's largest blob, pixels, shape (N,) (0 when there is none;
            reported for missing markers too).
        status: ``FOUND`` or the reason the marker is missing, shape (N,) (``STATUS_NAMES``).
    """

    pixels: NDArray[np.float64]
    areas: NDArray[np.int64]
    status: NDArray[np.int8]

    @property
    def found(self) -> NDArray[np.bool_]:
        """(N,) True where the marker was found."""
        return self.status == FOUND


def blob_fill(
    blob: NDArray[np.uint8], area: int, centre: NDArray[np.float64], model: CameraModel
) -> tuple[float, float]:
    """The share of a whole sphere marker's image that a blob covers (module docstring).

    Args:
        blob: the blob's mask (non-zero inside), any size that holds it, shape (h, w).
        area: the blob's area, pixels.
        centre: the blob's centroid ``[u, v]``, full-frame pixels, shape (2,).
        model: the camera (principal point, f / pitch).

    Returns:
        ``(fill, r)``: the fill, and the radius of the smallest circle enclosing the blob's pixel
        centres, pixels.
    """
    contours, _ = cv2.findContours(blob, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    _, radius = cv2.minEnclosingCircle(np.concatenate(contours))
    a, b = (centre - principal_point(model)) * (model.pixel_pitch / model.focal_length)
    cos_alpha = 1.0 / np.sqrt(1.0 + a * a + b * b)
    return float(area / (np.pi * (radius + 0.5) ** 2 * cos_alpha)), float(radius)


def _partial(
    labels: NDArray[np.integer],
    k: int,
    box: tuple[int, int, int, int],
    area: int,
    centre: NDArray[np.float64],
    model: CameraModel,
    min_fill: float,
) -> bool:
    """Whether blob k (of ``labels``, bounding box ``(x, y, w, h)``) fails the fill test."""
    x, y, w, h = box
    fill, radius = blob_fill(
        (labels[y : y + h, x : x + w] == k).astype(np.uint8), area, centre, model
    )
    return fill < min_fill - FILL_SLACK_PX / max(radius, 0.5)


def detect_markers(
    image: NDArray[np.uint8],
    model: CameraModel | None = None,
    origin: tuple[int, int] = (0, 0),
    bands: Sequence[ColourBand] = MARKER_BANDS,
    min_area: int = MIN_AREA_PX,
    min_fill: float = MIN_FILL,
) -> Detections:
    """Find each marker's centroid in an RGB image (module docstring).

    Args:
        image: RGB, uint8, shape (H, W, 3): a full frame or a window of one
            (`capture_bench.sensing.render_camera.render_frame`).
        model: the camera that took it, for the fill test; None skips that test.
        origin: ``(u0, v0)``, the full-frame pixel of the image's top-left pixel (a window's);
            added to the centroids.
        bands: one colour band per marker, in the order of the feature points.
        min_area: smallest blob counted as a marker, pixels, >= 1.
        min_fill: smallest fill of a found marker less ``FILL_SLACK_PX / r``, in [0, 1] (0: no
            fill test).

    Returns:
        `Detections` with N = len(bands).
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be RGB uint8 of shape (H, W, 3), got {img.dtype} {img.shape}")
    if min_area < 1:
        raise ValueError(f"min_area must be >= 1 pixel, got {min_area}")
    height, width = img.shape[:2]
    offset = np.asarray(origin, dtype=float)
    hsv = np.asarray(cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2HSV), dtype=np.uint8)
    n = len(bands)
    pixels = np.full((n, 2), np.nan)
    areas = np.zeros(n, dtype=np.int64)
    status = np.full(n, NO_BLOB, dtype=np.int8)
    for i, band in enumerate(bands):
        mask = colour_mask(hsv, band)
        cx, cy, cw, ch = cv2.boundingRect(mask)  # components only inside the colour's extent
        if cw == 0:
            continue
        count, labels, stats, centroids = cv2.connectedComponentsWithStats(
            mask[cy : cy + ch, cx : cx + cw], connectivity=8
        )
        blob_areas = stats[1:, cv2.CC_STAT_AREA]  # label 0 is the background
        order = np.argsort(blob_areas)[::-1]
        k = int(order[0]) + 1
        areas[i] = stats[k, cv2.CC_STAT_AREA]
        x, y = stats[k, cv2.CC_STAT_LEFT], stats[k, cv2.CC_STAT_TOP]
        w, h = stats[k, cv2.CC_STAT_WIDTH], stats[k, cv2.CC_STAT_HEIGHT]
        centre = centroids[k] + offset + (cx, cy)  # binary moments (m10 / m00, m01 / m00)
        if areas[i] < min_area:
            status[i] = TOO_SMALL
        elif x + cx == 0 or y + cy == 0 or x + cx + w == width or y + cy + h == height:
            status[i] = AT_BORDER
        elif count > 2 and blob_areas[order[1]] >= min_area:
            status[i] = SPLIT
        elif (
            model is not None
            and min_fill > 0.0
            and _partial(
                np.asarray(labels), k, (x, y, w, h), int(areas[i]), centre, model, min_fill
            )
        ):
            status[i] = PARTIAL
        else:
            status[i] = FOUND
            pixels[i] = centre
    return Detections(pixels=pixels, areas=areas, status=status)
