"""The ``python -m capture_bench zoo-hyperparams`` job: the RL Zoo's ``configs/zoo/<algo>.yml``
made from ``configs/algos/`` (`command`)."""
