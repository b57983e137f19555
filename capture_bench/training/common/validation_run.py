"""The periodic validation of ``train.py``: one deterministic episode per validation seed, all
stepped together in the batched
[`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv].

Sub-env i is reset on seed i of the list and its first episode is the one counted; the vector
env autoresets a sub-env the step after its episode ends (next-step autoreset), and whatever it
does after that is ignored, until every sub-env has ended its first episode. A sub-env seeded s
plays exactly the episode ``CaptureEnv(...).reset(seed=s)`` does (``tests/test_training_metrics.py``
checks the statistics equal those of single envs on the same seeds, to rounding).

Only the seeds given are used; ``Progress`` passes the first of ``Scenario.validation_seeds``,
never an evaluation seed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from capture_bench.envs.vector_env import sub_env_infos
from capture_bench.training.common.episode_stats import EpisodeStats, EpisodeTracker


def run_validation(
    predictor: Any,
    venv: Any,
    seeds: Sequence[int],
    normalize: Callable[[Any], Any] | None = None,
) -> list[EpisodeStats]:
    """Play one deterministic episode per seed in ``venv``; their statistics, in seed order.

    Args:
        predictor: anything with SB3's ``predict(observations, deterministic=True)`` taking a
            batch, shape (n, 16) (an SB3 model, an analytic controller).
        venv: a ``CaptureVectorEnv`` with ``len(seeds)`` sub-envs.
        seeds: one episode seed per sub-env.
        normalize: applied to the observation batch before ``predict`` (the model's
            ``VecNormalize.normalize_obs``), or None.
    """
    n = len(seeds)
    if venv.num_envs != n:
        raise ValueError(f"run_validation: {n} seeds for a vector env of {venv.num_envs} sub-envs")
    obs, _ = venv.reset(seed=[int(s) for s in seeds])
    tracker = EpisodeTracker(n)
    results: list[EpisodeStats | None] = [None] * n
    done = np.zeros(n, dtype=bool)  # sub-env i's first episode has ended
    while not done.all():
        inputs = obs if normalize is None else normalize(obs)
        action, _ = predictor.predict(inputs, deterministic=True)
        obs, rewards, terminated, truncated, info = venv.step(action)
        # a sub-env past its first episode is fed as not done with reward 0: it is never read
        live = ~done
        infos = [x if live[i] else {} for i, x in enumerate(sub_env_infos(info, n))]
        ended = (terminated | truncated) & live
        for i, stats in tracker.step(infos, ended, np.where(live, rewards, 0.0)):
            results[i] = stats
        done |= ended
    return [r for r in results if r is not None]
