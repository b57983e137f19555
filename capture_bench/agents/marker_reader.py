"""The target's markers read from an area-sampled image to a fraction of a pixel, and the features
a pixel policy takes from them (`MarkerKeypointExtractor`, declared as ``marker_keypoints``).

A marker in the wide image (``image_supersample`` > 1) is a disc about 3 pixels across whose edge
pixels mix its colour with the background's in proportion to how much of each pixel it covers.
Weights linear in that coverage have their centroid at the disc's centre to a small fraction of a
pixel (`local_centroid`); a softmax of the same map is pulled towards its largest pixel. Depth is
in the markers' spacing, which shrinks 0.013 wide-image pixels for each millimetre the target
recedes (docs/pixels.md), so the reader has to be that precise. One frame is read as:

1. **detection**: a 3 x 3 convolution to `HIDDEN` maps, a ReLU and a 1 x 1 convolution give one
   logit map per marker (fitted by cross-entropy to the marker's pixel, `heatmap_loss`); each
   map's largest value places a window of (2 `WINDOW` + 1)^2 pixels;
2. **weights**: a per-pixel network of the pixel's colour (`colour_channels`: RGB, saturation and
   chromaticity, which do not change with the shading across a lit sphere), 1 x 1 convolutions
   to `HIDDEN` maps (a ReLU) then one per marker (a sharp softplus, β = `SHARPNESS`): positive
   everywhere. A ReLU there can die for a whole marker in a fit, whose keypoint is then the
   window's centre, half a pixel off;
3. **keypoint**: the weights' centroid in the window (`local_centroid`) and the weight found.

The reader is fitted by `heatmap_loss` and `keypoint_loss`, whose pixel error is robust: a marker
the gripper or the block hides has no centroid to find, and its error, pixels off, would
otherwise outweigh the visible markers' tenths of a pixel or less.

The features of a frame (`keypoint_features`): the keypoints in [-1, 1] (`to_unit`), the log of
each one's weight and the log distances between them. X_E is not read: its place is in the arm's
state.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from capture_bench.sim.markers import MARKER_COLOURS

MARKERS = len(MARKER_COLOURS)  # one keypoint per marker
HIDDEN = 16  # maps of the detection's and of the weights' hidden layer
WINDOW = 3  # the window's half side, wide-image pixels: a marker and a pixel either side
SHARPNESS = 10.0  # beta of the weights' softplus: near a ReLU, never without a gradient
MIN_STD = 0.01  # the least standard deviation a feature is divided by
ROBUST_PX = 0.5  # pixels: the keypoint error beyond which `keypoint_loss` levels off
HAND_GATE = 0.9  # the hand reader's least cosine between a pixel's chromatic drop and a marker's
SHOWN = 0.5  # a marker shows where its hand-read weight is at least this share of the largest


def window_pixels(
    maps: torch.Tensor, half: int, peak: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The (2 half + 1)^2 pixels around each map's ``peak`` (B, K), a flat pixel index (default:
    the map's largest value), the window moved inside the map (B, K, H, W) at the edges: their
    rows, columns, (B, K, (2 half + 1)^2) each, and the maps' values there."""
    b, k, h, w = maps.shape
    peak = maps.flatten(2).argmax(-1) if peak is None else peak
    side = 2 * half + 1
    r0 = (peak // w).clamp(half, h - 1 - half) - half
    c0 = (peak % w).clamp(half, w - 1 - half) - half
    offsets = torch.arange(side, device=maps.device)
    rows = (r0[..., None] + offsets)[..., :, None].expand(b, k, side, side).reshape(b, k, -1)
    cols = (c0[..., None] + offsets)[..., None, :].expand(b, k, side, side).reshape(b, k, -1)
    return rows, cols, maps.flatten(2).gather(-1, rows * w + cols)


def local_centroid(
    maps: torch.Tensor, half: int, peak: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each non-negative map's (B, K, H, W) centroid over the (2 half + 1)^2 pixels around
    ``peak`` (`window_pixels`), [x, y] in pixels, (B, K, 2), and the weight it found there,
    (B, K). The weights are the map's values themselves, not their softmax: where a map is
    linear in how much of a pixel a marker covers (an area-sampled edge pixel), the centroid is
    the marker's sub-pixel centre. An empty window gives its centre."""
    rows, cols, weights = window_pixels(maps, half, peak)
    return _centroid(rows, cols, weights)


def _centroid(
    rows: torch.Tensor, cols: torch.Tensor, weights: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The centroid of ``weights`` at the window pixels ``rows``, ``cols`` (B, K, P each),
    [x, y], (B, K, 2), and their sum (B, K); an empty window gives its centre."""
    mass = weights.sum(-1)
    centre_x, centre_y = cols.float().mean(-1), rows.float().mean(-1)
    x = centre_x + (weights * (cols - centre_x[..., None])).sum(-1) / (mass + 1e-6)
    y = centre_y + (weights * (rows - centre_y[..., None])).sum(-1) / (mass + 1e-6)
    return torch.stack((x, y), dim=-1).float(), mass


def colour_channels(x: torch.Tensor) -> torch.Tensor:
    """An RGB image (B, 3, H, W) in [0, 1] -> (B, 10, H, W): RGB, saturation (max - min) / max,
    chromaticity (each channel over their sum) and saturation times chromaticity. Saturation and
    chromaticity do not change with the shading across a lit sphere, so a marker's weight can
    follow how much of a pixel it covers and not how brightly it is lit there."""
    top, low = x.max(1, keepdim=True).values, x.min(1, keepdim=True).values
    saturation = (top - low) / (top + 1e-3)
    chroma = x / (x.sum(1, keepdim=True) + 1e-3)
    return torch.cat((x, saturation, chroma, saturation * chroma), dim=1)


def heatmap_loss(logits: torch.Tensor, points: torch.Tensor, inside: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of the first F detection maps' softmax over the view (B, K, H, W) against
    the points (B, F, 2), each spread bilinearly over the four pixels around it; points outside
    the view (``inside`` (B, F) false) count nothing."""
    b, _, h, w = logits.shape
    f = points.shape[1]
    logp = torch.log_softmax(logits[:, :f].flatten(2), dim=-1)
    xy = points.clamp(min=0.0)
    x0 = xy[..., 0].floor().clamp(max=w - 2)
    y0 = xy[..., 1].floor().clamp(max=h - 2)
    fx, fy = (xy[..., 0] - x0).clamp(0, 1), (xy[..., 1] - y0).clamp(0, 1)
    loss = torch.zeros(b, f, device=logits.device)
    for dx, dy, share in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                          (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):  # fmt: skip
        index = ((y0 + dy) * w + x0 + dx).long()
        loss = loss - share * logp.gather(-1, index[..., None])[..., 0]
    return (inside * loss).mean()


def keypoint_loss(pixels: torch.Tensor, points: torch.Tensor, inside: torch.Tensor) -> torch.Tensor:
    """The keypoints' (B, K, 2) robust error against the points (B, K, 2), pixels: the mean over
    the points inside the view (``inside`` (B, K)) of e^2 / (e^2 + `ROBUST_PX`^2), e the pixel
    error: near the squared error (over `ROBUST_PX`^2) below `ROBUST_PX`, levelling off to 1
    beyond it, so that a hidden marker (no centroid to find) weighs little."""
    squared = torch.sum((pixels - points) ** 2, dim=-1)
    return torch.mean(inside * squared / (squared + ROBUST_PX**2))


def to_unit(pixels: torch.Tensor, size: int) -> torch.Tensor:
    """Pixels of a ``size``-pixel view -> [-1, 1] from its first to its last pixel centre."""
    return pixels * 2.0 / (size - 1) - 1.0


def keypoint_features(xy: torch.Tensor, mass: torch.Tensor) -> torch.Tensor:
    """Keypoints (B, K, 2) in [-1, 1] (`to_unit`) and how much each found, (B, K) -> features:
    the keypoints, ``mass`` and the log distances between keypoints (the markers' spacing, which
    is what tells depth)."""
    i, j = torch.triu_indices(xy.shape[1], xy.shape[1], 1)
    spacing = torch.log(torch.linalg.vector_norm(xy[:, i] - xy[:, j], dim=-1) + 1e-3)
    return torch.cat((xy.flatten(1), mass, spacing), dim=1)


def feature_width(keypoints: int) -> int:
    """How many features `keypoint_features` gives for ``keypoints`` keypoints."""
    return 3 * keypoints + keypoints * (keypoints - 1) // 2


class MarkerReader(nn.Module):
    """One frame (B, 3, H, W) in [0, 1] -> the markers' keypoints in pixels (B, `MARKERS`, 2),
    the weight each found (B, `MARKERS`) and the detection logits (B, `MARKERS`, H, W) (module
    docstring, 1-3)."""

    def __init__(self, window: int = WINDOW) -> None:
        super().__init__()
        self.window = window
        self.detect = nn.Sequential(
            nn.Conv2d(3, HIDDEN, 3, padding=1), nn.ReLU(), nn.Conv2d(HIDDEN, MARKERS, 1)
        )
        self.weights = nn.Sequential(
            nn.Conv2d(10, HIDDEN, 1),
            nn.ReLU(),
            nn.Conv2d(HIDDEN, MARKERS, 1),
            nn.Softplus(beta=SHARPNESS),
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The reading; the weights are computed at the windows' pixels alone (`weight_maps`
        over the whole frame gives the same there)."""
        logits = self.detect(x)
        b, k, h, w = logits.shape
        rows, cols, _ = window_pixels(logits, self.window)  # (B, K, P) each
        index = (rows * w + cols).reshape(b, 1, -1).expand(-1, x.shape[1], -1)
        colours = x.flatten(2).gather(-1, index).reshape(b, x.shape[1], k * rows.shape[-1], 1)
        weights = self.weights(colour_channels(colours))  # (B, K maps, K * P, 1)
        own = weights[:, :, :, 0].reshape(b, k, k, -1).diagonal(dim1=1, dim2=2)  # (B, P, K)
        pixels, mass = _centroid(rows, cols, own.transpose(1, 2))  # map k's weights, window k
        return pixels, mass, logits

    def weight_maps(self, x: torch.Tensor) -> torch.Tensor:
        """Every pixel's weight for each marker, (B, K, H, W)."""
        return self.weights(colour_channels(x))


class MarkerKeypointExtractor(BaseFeaturesExtractor):
    """The pixel observation's features from the markers' keypoints: each frame of the wide
    image (``image``, its frames stacked along the channels) read by one `MarkerReader`, its
    `keypoint_features` (the log weights as found), the frames' side by side, oldest first; the
    arm's state beside them (the keys of its observation space alone: an asymmetric critic's
    ``critic_state`` is not read). Each feature is standardised by ``mean`` and ``std`` (buffers,
    kept with the weights; 0 and 1 until `standardise` sets them from a batch of observations,
    as DAgger's fit does), as the spacings' millimetre changes are thousandths of their log.
    Declared as ``marker_keypoints``; it reads the wide image alone (no end-effector crop)."""

    def __init__(self, observation_space: gym.spaces.Dict) -> None:
        spaces = observation_space.spaces
        images = [k for k, box in spaces.items() if len(box.shape) == 3]
        if images != ["image"]:
            raise ValueError(
                f"marker_keypoints reads the wide image alone; the observation has the images "
                f"{images}: leave out ee_crop, or use the features extractor 'keypoints'"
            )
        channels, height, width = spaces["image"].shape
        if height != width or channels % 3:
            raise ValueError(
                f"marker_keypoints reads square RGB frames; the image is {spaces['image'].shape}"
            )
        self.frames, self.size = channels // 3, width
        self.flat_keys = sorted(k for k in spaces if k != "image")
        flat = sum(int(np.prod(spaces[k].shape)) for k in self.flat_keys)
        size = self.frames * feature_width(MARKERS) + flat
        super().__init__(observation_space, features_dim=size)
        self.reader = MarkerReader()
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("std", torch.ones(size))

    def read(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The newest frame's reading (`MarkerReader`) of images (B, 3 S, H, W) in [0, 1]."""
        return self.reader(image[:, -3:])

    def raw(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        """The features before standardising."""
        image = observations["image"]
        b = image.shape[0]
        frames = image.reshape(b * self.frames, 3, self.size, self.size)
        pixels, mass, _ = self.reader(frames)
        found = keypoint_features(to_unit(pixels, self.size), torch.log(mass + 1e-3))
        rest = [observations[k].flatten(1) for k in self.flat_keys]
        return torch.cat([found.reshape(b, -1), *rest], dim=1)

    @torch.no_grad()
    def standardise(self, observations: dict[str, torch.Tensor], chunk: int = 256) -> None:
        """Set ``mean`` and ``std`` to those of the raw features of ``observations`` (read
        ``chunk`` rows at a time); a std below `MIN_STD` counts as `MIN_STD`, so that a feature
        nearly constant in this batch (a reader not fitted yet) is not magnified later."""
        n = len(observations["image"])
        x = torch.cat([
            self.raw({k: v[i : i + chunk] for k, v in observations.items()})
            for i in range(0, n, chunk)
        ])  # fmt: skip
        self.mean.copy_(x.mean(0))
        self.std.copy_(x.std(0).clamp_min(MIN_STD))

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        return (self.raw(observations) - self.mean) / self.std


class HandReader(nn.Module):
    """The markers read by hand, no parameters: one frame (B, 3, H, W) in [0, 1] -> keypoints
    (B, `MARKERS`, 2), weights (B, `MARKERS`) and no logits, as `MarkerReader` gives them. Each
    pixel's weight for marker k is one less its darkest channel (on the scene's white
    background, the share of the pixel a marker covers, however lit, for colours with a channel
    near 0) where the chromatic part of its drop from white points within `HAND_GATE` (cosine)
    of marker k's, else 0; the window is the 5 x 5 pixels around the largest 3 x 3 sum of those
    weights, and the keypoint their centroid there (`local_centroid`). What a reader of the
    frame's colours alone reaches, hidden markers and all."""

    def __init__(self) -> None:
        super().__init__()
        drop = 1.0 - torch.tensor([c[:3] for c in MARKER_COLOURS])
        chroma = drop - drop.mean(1, keepdim=True)
        self.register_buffer("chroma", chroma / torch.linalg.vector_norm(chroma, dim=1)[:, None])

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, None]:
        drop = 1.0 - x
        chroma = drop - drop.mean(1, keepdim=True)
        norm = torch.linalg.vector_norm(chroma, dim=1)[:, None] + 1e-6
        cosine = torch.einsum("bchw,kc->bkhw", chroma, self.chroma) / norm
        weights = drop.max(1, keepdim=True).values * (cosine > HAND_GATE)
        peak = nn.functional.avg_pool2d(weights, 3, 1, 1).flatten(2).argmax(-1)
        pixels, mass = local_centroid(weights, 2, peak)
        return pixels, mass, None


def shown_markers(mass: np.ndarray) -> np.ndarray:
    """Which markers show, (N, `MARKERS`) bool, from their hand-read weights (N, `MARKERS`): at
    least `SHOWN` of the frame's largest, and not none."""
    return (mass >= SHOWN * mass.max(axis=1, keepdims=True)) & (mass > 0)
