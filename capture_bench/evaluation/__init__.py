"""Evaluation: rollouts, metrics and the leaderboard report (``python evaluate.py``).

Modules, in the order data flows:

* :mod:`~capture_bench.evaluation.suites`: leaderboard suites (``configs/suites/*.yaml``);
* :mod:`~capture_bench.evaluation.agents_loading`: agent specs (built-in, trained model,
  ``module:Class``) -> agents;
* :mod:`~capture_bench.evaluation.rollout`: one episode -> one :class:`EpisodeRecord`;
* :mod:`~capture_bench.evaluation.backends`: many episodes, serially, in processes or on Ray;
* :mod:`~capture_bench.evaluation.metrics`, :mod:`~capture_bench.evaluation.aggregate`: records ->
  estimates with 95% intervals, survival curves, paired comparisons, the ranking;
* :mod:`~capture_bench.evaluation.report`, :mod:`~capture_bench.evaluation.plots`: the report;
* :mod:`~capture_bench.evaluation.pipeline`: all of it behind ``evaluate.py``.
"""

from capture_bench.evaluation.errors import AgentSpecError, EvaluationError, SuiteError
from capture_bench.evaluation.rollout import EpisodeRecord, run_episode

__all__ = ["AgentSpecError", "EpisodeRecord", "EvaluationError", "SuiteError", "run_episode"]
