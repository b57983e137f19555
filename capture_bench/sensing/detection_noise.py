"""The rendered camera's detection error as its image settings make it: the per-axis RMS of the
found markers' centroids about eq. 2's projection of their true centres at the frame's time, the
EKF's measurement noise in rendered mode.

`detection_sigma` is a fit of what ``scripts/detection_error.py`` measures in episodes of
``paper_rendered`` (the paper's controller on validation seeds, 1000 frames with a marker found;
the table and its commands: ``docs/rendered_camera.md``), three terms added in quadrature:

* **optics blur and the floor**: the RMS measured at ``psf_sigma`` alone (`PSF_KNOTS`,
  `PSF_RMS`), linear between the knots, the last value beyond them. With no blur it is the
  floor of the episodes' frames (0.060 px: the pixel grid, and markers partly hidden yet
  accepted). Blur of 0.65 px or more pulls each centroid toward the marker's lit side: the
  saturation threshold eats more of the darker, shaded limb as it mixes with the background;
* **sensor noise**: what ``image_noise`` adds to the variance, measured at ``psf_sigma`` 0, 0.5
  and 1 (`NOISE_PSF_KNOTS`) and ``image_noise`` 0-12 grey levels (`NOISE_KNOTS`, `NOISE_RMS`),
  bilinear between them, held at their edges (12 grey levels, 1 px); the detector's thresholds
  stand far from a marker's colour, so noise costs little up to 8 grey levels; at 16 a fifth of
  the markers are lost, and the error is no longer a centroid's (the fit's range ends at 12);
* **exposure**: the centroid lies at the exposure's mean position, half the exposure's motion
  behind eq. 2 at t: ``LAG_GAIN exposure v``, v the target's RMS speed, m/s (per axis, a random
  direction: ``f / (2 sqrt(3) d pitch)`` is 513 px per m at d = 1.2 m; fitted 553).
"""

from __future__ import annotations

import math

import numpy as np

#: ``camera.psf_sigma`` knots, px, and the RMS per axis measured there (image_noise 0, no
#: exposure), px.
PSF_KNOTS = (0.0, 0.5, 0.6, 0.65, 0.7, 0.8, 1.0, 1.5, 2.0, 3.0, 5.0)
PSF_RMS = (0.0598, 0.0619, 0.0717, 0.1300, 0.1427, 0.1306, 0.1266, 0.1500, 0.1516, 0.2179, 0.2497)
#: ``camera.image_noise`` knots, grey levels, at each ``psf_sigma`` of `NOISE_PSF_KNOTS`, px.
NOISE_KNOTS = (0.0, 4.0, 8.0, 12.0)
NOISE_PSF_KNOTS = (0.0, 0.5, 1.0)
#: RMS per axis measured at (NOISE_PSF_KNOTS[i], NOISE_KNOTS[j]), no exposure, px.
NOISE_RMS = (
    (0.0598, 0.0598, 0.0601, 0.0745),
    (0.0619, 0.0621, 0.0642, 0.0900),
    (0.1266, 0.1249, 0.1364, 0.1654),
)
#: The exposure's lag per axis over exposure (s) times the target's RMS speed (m/s), px.
LAG_GAIN = 553.0


def detection_sigma(psf_sigma: float, image_noise: float, exposure: float, speed: float) -> float:
    """The rendered camera's detection error, RMS per axis, pixels (module docstring).

    Args:
        psf_sigma: ``camera.psf_sigma``, px, >= 0.
        image_noise: ``camera.image_noise``, grey levels, >= 0.
        exposure: ``camera.exposure``, s, >= 0.
        speed: the target's RMS speed, m/s, >= 0.
    """
    base = float(np.interp(psf_sigma, PSF_KNOTS, PSF_RMS))
    lag = LAG_GAIN * exposure * speed
    return math.sqrt(base**2 + noise_variance(psf_sigma, image_noise) + lag**2)


def noise_variance(psf_sigma: float, image_noise: float) -> float:
    """What ``image_noise`` adds to the detection error's variance at ``psf_sigma``, px^2:
    bilinear in the measured excess ``NOISE_RMS^2 - NOISE_RMS[:, 0]^2`` (>= 0)."""
    rms = np.asarray(NOISE_RMS)
    excess = np.maximum(rms**2 - rms[:, :1] ** 2, 0.0)
    along = [float(np.interp(image_noise, NOISE_KNOTS, row)) for row in excess]
    return float(np.interp(psf_sigma, NOISE_PSF_KNOTS, along))


def rms_speed(low: float, high: float) -> float:
    """The RMS of a speed drawn uniformly from ``[low, high]``, m/s."""
    return math.sqrt((low * low + low * high + high * high) / 3.0)
