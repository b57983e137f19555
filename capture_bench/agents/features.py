"""Features a policy network may compute from the observation before its layers: entries that
resolve millimetres, without changing the env's observation (its effect: docs/results/ablation.md),
and, for the pixel observation, keypoints that keep the image's positions
(`SpatialSoftmaxExtractor`).

The observation's relative vector (entries 12-14, eq. 13's predicted X^_T' - X_E, scaled by
0.5 m) is of order 0.002 at eq. 20's 1 mm tolerance: to a network that starts with weights of
order one, the last millimetre is invisible. `RelativeLogDistance` appends

=====  ==============================================================  =====================
index  quantity                                                        decodes to
=====  ==============================================================  =====================
16-18  unit direction u = r / |r| of the predicted relative vector r   u
19     log10(max(|r|, 1 um) / 1 mm) / 3                                |r| = 1 mm * 1000**x
=====  ==============================================================  =====================

so 1 m reads 1, 1 mm reads 0 and 1 um reads -1 (`relative_features` is the same in numpy,
and `decode_relative_features` undoes it). It is a function of the observation alone, so a
policy that uses it acts in any capture-bench env; the safe policy format declares it by name
(``policy_kwargs.features_extractor``, `FEATURE_EXTRACTORS`). It reads the raw observation:
it cannot be combined with ``normalize: true`` (train.py refuses the pair).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from numpy.typing import NDArray
from stable_baselines3.common.torch_layers import (
    BaseFeaturesExtractor,
    CombinedExtractor,
    FlattenExtractor,
)

from capture_bench.agents.marker_reader import MarkerKeypointExtractor
from capture_bench.task.observation import OBSERVATION_SIZE, RELATIVE_SCALE, SLICES

MIN_DISTANCE = 1e-6  # m: below it the direction is noise and the log is clamped
DISTANCE_UNIT = 1e-3  # m: log distance 0 at eq. 20's tolerance
LOG_SCALE = 3.0  # decades per unit: 1 um .. 1 m reads -1 .. 1
EXTRA_SIZE = 4


def relative_features(obs: NDArray) -> NDArray[np.float32]:
    """The 4 entries `RelativeLogDistance` appends, for observations (..., 16)."""
    o = np.asarray(obs, dtype=np.float32)
    r = o[..., SLICES["relative_position"]] * np.float32(RELATIVE_SCALE)
    d = np.maximum(np.linalg.norm(r, axis=-1, keepdims=True), np.float32(MIN_DISTANCE))
    log_d = np.log10(d / np.float32(DISTANCE_UNIT)) / np.float32(LOG_SCALE)
    return np.concatenate((r / d, log_d), axis=-1).astype(np.float32)


def decode_relative_features(features: NDArray) -> tuple[NDArray, NDArray]:
    """(unit direction (..., 3), distance (...,) m) from the 4 appended entries."""
    f = np.asarray(features, dtype=np.float64)
    return f[..., :3], DISTANCE_UNIT * 10.0 ** (LOG_SCALE * f[..., 3])


class RelativeLogDistance(BaseFeaturesExtractor):
    """The observation (16 entries) followed by the unit direction and the log distance of the
    predicted relative vector (module docstring): 20 features."""

    def __init__(self, observation_space: gym.spaces.Box) -> None:
        if observation_space.shape != (OBSERVATION_SIZE,):
            raise ValueError(
                f"RelativeLogDistance reads capture-bench observations of shape "
                f"({OBSERVATION_SIZE},), got {observation_space.shape}"
            )
        super().__init__(observation_space, features_dim=OBSERVATION_SIZE + EXTRA_SIZE)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        r = observations[:, SLICES["relative_position"]] * RELATIVE_SCALE
        d = torch.linalg.vector_norm(r, dim=1, keepdim=True).clamp_min(MIN_DISTANCE)
        log_d = torch.log10(d / DISTANCE_UNIT) / LOG_SCALE
        return torch.cat((observations, r / d, log_d), dim=1)


class SpatialSoftmax(torch.nn.Module):
    """Feature maps (B, K, H, W) -> K keypoints (B, 2 K): each map's softmax over its pixels
    (divided by a learned temperature) and the expected pixel position under it, x then y for
    each map, in [-1, 1] from the image's first to its last pixel centre (Levine, Finn, Darrell
    & Abbeel 2016). An expectation, so a keypoint moves by a fraction of a pixel when the image
    does."""

    def __init__(self) -> None:
        super().__init__()
        self.log_temperature = torch.nn.Parameter(torch.zeros(1))

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        b, k, h, w = maps.shape
        weights = torch.softmax(maps.reshape(b, k, h * w) / self.log_temperature.exp(), dim=-1)
        ys, xs = torch.meshgrid(
            torch.linspace(-1.0, 1.0, h, device=maps.device),
            torch.linspace(-1.0, 1.0, w, device=maps.device),
            indexing="ij",
        )
        x = (weights * xs.reshape(1, 1, -1)).sum(-1)
        y = (weights * ys.reshape(1, 1, -1)).sum(-1)
        return torch.stack((x, y), dim=-1).reshape(b, 2 * k)


KEYPOINTS = 16  # keypoints per image of `SpatialSoftmaxExtractor`


def keypoint_network(channels: int) -> torch.nn.Sequential:
    """An image (B, channels, H, W) in [0, 1] -> `KEYPOINTS` keypoints (B, 32): a 5 x 5
    convolution at stride 1 (every pixel a position), a 3 x 3 at stride 2, a 3 x 3 at stride 1
    to `KEYPOINTS` maps, then `SpatialSoftmax`."""
    return torch.nn.Sequential(
        torch.nn.Conv2d(channels, 16, 5, stride=1, padding=2),
        torch.nn.ReLU(),
        torch.nn.Conv2d(16, 32, 3, stride=2, padding=1),
        torch.nn.ReLU(),
        torch.nn.Conv2d(32, KEYPOINTS, 3, stride=1, padding=1),
        SpatialSoftmax(),
    )


class SpatialSoftmaxExtractor(BaseFeaturesExtractor):
    """The pixel observation's features that keep position: each image (``image``, and
    ``ee_image`` where given; frames stacked along the channels) through its own
    `keypoint_network` (`KEYPOINTS` x, y pairs), the other keys (the arm's state) flattened
    beside them. Declared as ``keypoints``."""

    def __init__(self, observation_space: gym.spaces.Dict) -> None:
        super().__init__(observation_space, features_dim=1)
        extractors: dict[str, torch.nn.Module] = {}
        size = 0
        for key, box in observation_space.spaces.items():
            if len(box.shape) == 3:
                extractors[key] = keypoint_network(box.shape[0])
                size += 2 * KEYPOINTS
            else:
                extractors[key] = torch.nn.Flatten()
                size += int(np.prod(box.shape))
        self.extractors = torch.nn.ModuleDict(extractors)
        self._features_dim = size

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        return torch.cat([net(observations[key]) for key, net in self.extractors.items()], dim=1)


#: Declared name -> features extractor class (``flatten``: SB3's default for a Box observation,
#: the raw observation; ``combined``: SB3's default for a ``Dict`` one, the pixel observation's
#: image through SB3's NatureCNN beside the flattened arm state; ``keypoints``: each image
#: to keypoints that keep its positions, `SpatialSoftmaxExtractor`; ``marker_keypoints``: the
#: wide image's markers read to a fraction of a pixel, frame by frame, `MarkerKeypointExtractor`).
FEATURE_EXTRACTORS: dict[str, type[BaseFeaturesExtractor]] = {
    "flatten": FlattenExtractor,
    "relative_log_distance": RelativeLogDistance,
    "combined": CombinedExtractor,
    "keypoints": SpatialSoftmaxExtractor,
    "marker_keypoints": MarkerKeypointExtractor,
}
