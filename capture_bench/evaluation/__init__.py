"""Evaluation: rollouts, metrics and the leaderboard report (``python evaluate.py``).

Modules, in the order data flows:

* `suites`: leaderboard suites (``configs/suites/*.yaml``);
* `agents_loading`: agent specs (built-in, trained model,
  ``module:Class``) -> agents;
* `rollout`: one episode -> one `EpisodeRecord`;
* `backends`: many episodes, serially, in processes or on Ray;
* `metrics`, `aggregate`: records ->
  estimates with 95% intervals, survival curves, paired comparisons, the ranking;
* `report`, `plots`: the report;
* `pipeline`: all of it behind ``evaluate.py``.
"""

from capture_bench.evaluation.errors import AgentSpecError, EvaluationError, SuiteError
from capture_bench.evaluation.rollout import EpisodeRecord, run_episode

__all__ = ["AgentSpecError", "EpisodeRecord", "EvaluationError", "SuiteError", "run_episode"]
