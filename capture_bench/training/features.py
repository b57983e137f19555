"""The import path that SB3 ``.zip`` files saved by ``train.py`` name for their features extractor
(pickled as ``capture_bench.training.features.RelativeLogDistance``): the class lives in
`capture_bench.agents.features`, where policy loading finds it."""

from capture_bench.agents.features import RelativeLogDistance

__all__ = ["RelativeLogDistance"]
