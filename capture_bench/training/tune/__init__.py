"""The ``tune.py`` job: Optuna's search over an algorithm's hyper-parameters on a scenario. The
command (`command`), its options (`options`), one trial (`trial`), the study's settings, storage
and seeded sampler (`study`, `storage`, `sampler`), where trials run (`workers`), the search
spaces (`search_spaces`) and the study's outputs (``best.yaml``, ``trials.csv``, plots:
`outputs`)."""
