"""Drawing the target's and the end-effector's traces into a rendered image (a small rasteriser).

`render` projects the traces (global frame, m) with the
camera's view-projection matrix and draws them over pybullet's image.
"""

from __future__ import annotations

import numpy as np

from capture_bench.sim.kinematics import FloatArray


def project_points(
    points: FloatArray, transform: FloatArray, width: int, height: int
) -> FloatArray:
    """Pixel coordinates (u right, v down), shape (N, 2); NaN for points behind the camera."""
    clip = np.c_[points, np.ones(len(points))] @ transform.T
    w = clip[:, 3:4]
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc = np.where(w > 1e-9, clip[:, :2] / w, np.nan)
    return np.c_[(ndc[:, 0] + 1.0) * 0.5 * width, (1.0 - ndc[:, 1]) * 0.5 * height]


def draw_polyline(image: np.ndarray, pixels: FloatArray, colour: tuple[int, ...]) -> None:
    """Draw a 2-pixel-wide polyline through ``pixels`` (N, 2) into ``image`` in place."""
    height, width = image.shape[:2]
    pixels = np.clip(pixels, -1e6, 1e6)  # NaN stays NaN
    if len(pixels) == 1:
        pixels = np.repeat(pixels, 2, axis=0)
    a, b = pixels[:-1], pixels[1:]
    ok = np.all(np.isfinite(a) & np.isfinite(b), axis=1)
    a, b = a[ok], b[ok]
    if len(a) == 0:
        return
    limit = 4 * (width + height)  # far off-screen segments: sample coarsely, never huge arrays
    n = np.minimum(np.ceil(np.abs(b - a).max(axis=1)).astype(int), limit) + 1
    segment = np.repeat(np.arange(len(n)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(np.maximum(n - 1, 1), n)
    samples = np.rint(a[segment] + (b - a)[segment] * t[:, None]).astype(int)
    for du, dv in ((0, 0), (1, 0), (0, 1), (1, 1)):
        u, v = samples[:, 0] + du, samples[:, 1] + dv
        inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
        image[v[inside], u[inside]] = colour
