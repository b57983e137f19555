"""The ``train.py`` job: its command (`command`, installed as ``capture-bench-train``) and the
shipping of a finished run as a model with its card (`model_card`, ``python -m
capture_bench.training.train.model_card``)."""
