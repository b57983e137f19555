"""The per-episode score: how close an episode came to its physical limit, in [0, 1].

``physical limit / capture time`` for a capture (1 = as fast as physically possible; the ratio of
capture time to the limit is at least 1 up to the capture tolerance), 1 for a capture whose bound
is not finite and positive (a capture the bound says is impossible counts as fastest), 0 for a
failure. A capture always beats a failure, and a faster capture a slower one.

The evaluation report's probability of improvement and its aggregate statistics (rliable) score
the leaderboard's episodes with it; train.py's validation reports its mean (``mean_score``).
"""

from __future__ import annotations

import math


def episode_score(captured: bool, ratio_to_limit: float) -> float:
    """The score of one episode (module docstring).

    Args:
        captured: the episode ended with a capture.
        ratio_to_limit: capture time / physical-limit time; NaN where the episode did not capture
            or its bound is not finite and positive.
    """
    if not captured:
        return 0.0
    if math.isfinite(ratio_to_limit) and ratio_to_limit > 0:
        return 1.0 / ratio_to_limit
    return 1.0
