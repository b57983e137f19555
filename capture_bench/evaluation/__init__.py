"""Evaluation: rollouts, metrics and the leaderboard report (``python evaluate.py``).

Two sub-packages, in the order data flows:

* `running`: suites, agents, rollouts (one episode -> one `EpisodeRecord`), the backends that
  play many episodes (serially, in processes or on Ray) and the GIFs of evaluated episodes;
* `reporting`: records -> estimates with 95% intervals, survival curves, paired comparisons, the
  ranking, the report's sections and figures, report folders read back, merged and compared with
  the published one;

and on top `cli` (``evaluate.py``'s options and refusals), `pipeline` (all of it behind
``evaluate.py``) and `errors` (the one-line errors both raise). `running` never imports
`reporting`.
"""

from capture_bench.evaluation.errors import AgentSpecError, EvaluationError, SuiteError
from capture_bench.evaluation.running.rollout import EpisodeRecord, run_episode

__all__ = ["AgentSpecError", "EpisodeRecord", "EvaluationError", "SuiteError", "run_episode"]
