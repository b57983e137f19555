"""Features a policy network may compute from the observation before its layers: entries that
resolve millimetres, without changing the env's observation (its effect: docs/results/ablation.md).

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


#: Declared name -> features extractor class (``flatten``: SB3's default for a Box observation,
#: the raw observation; ``combined``: SB3's default for a ``Dict`` one, the pixel observation's
#: image through SB3's NatureCNN beside the flattened arm state).
FEATURE_EXTRACTORS: dict[str, type[BaseFeaturesExtractor]] = {
    "flatten": FlattenExtractor,
    "relative_log_distance": RelativeLogDistance,
    "combined": CombinedExtractor,
}
