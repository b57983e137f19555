"""scripts/pixel_depth.py: the saturation-weighted reading finds an area-sampled marker's
sub-pixel centre, and on the pixel env's own area-sampled images it locates the target in depth
far better than on point-sampled ones."""

from __future__ import annotations

import numpy as np

from capture_bench.sim.markers import BLOCK_COLOUR, MARKER_COLOURS


def _area_sampled_discs(centres: np.ndarray, radius: float, size: int, m: int) -> np.ndarray:
    """Discs of the marker colours on the block's grey, each pixel the mean of m x m samples at
    its sub-pixel centres (pixel centres at whole numbers), uint8 RGB (size, size, 3)."""
    sub = (np.arange(size * m) + 0.5) / m - 0.5
    xs, ys = np.meshgrid(sub, sub)
    image = np.empty((size * m, size * m, 3))
    image[...] = np.asarray(BLOCK_COLOUR[:3]) * 255.0
    for (cx, cy), colour in zip(centres, MARKER_COLOURS, strict=True):
        image[np.hypot(xs - cx, ys - cy) <= radius] = np.asarray(colour[:3]) * 255.0
    return np.rint(image.reshape(size, m, size, m, 3).mean(axis=(1, 3))).astype(np.uint8)


def test_the_reading_finds_an_area_sampled_discs_centre_to_a_tenth_of_a_pixel(load_script):
    pixel_depth = load_script("pixel_depth")
    centres = np.array([[6.3, 5.8], [17.55, 6.1], [6.05, 17.4], [17.2, 17.77]])
    read = pixel_depth.read_markers(_area_sampled_discs(centres, 1.6, 24, 11))
    np.testing.assert_allclose(read, centres, atol=0.08)
    point = pixel_depth.read_markers(_area_sampled_discs(centres, 1.6, 24, 1))
    assert np.abs(point - centres).max() > 0.1  # point sampling: the whole-pixel blob's centre


def test_area_sampling_locates_the_target_in_depth_where_point_sampling_cannot(load_script):
    pixel_depth = load_script("pixel_depth")
    point = pixel_depth.depth_reading("paper", 1, 8)
    area = pixel_depth.depth_reading("paper", 11, 8)
    assert len(area.errors) >= 12 and len(point.errors) >= 12
    got, was = area.summary(), point.summary()
    assert got["depth_mm"] < 3.0 and got["across_x_mm"] < 0.5 and got["across_z_mm"] < 0.5
    assert was["depth_mm"] > 2 * got["depth_mm"]
