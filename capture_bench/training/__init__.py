"""Training: one folder per job over what the jobs share.

* `config`: the hyper-parameter files and ``train.py``'s options;
* `common`: one training run (`common.run`, what ``train.py`` is), the envs and model it builds,
  checkpoints, validation and the policy's safe export;
* the jobs, none importing another: `train` (``train.py``, model cards), `tune` (``tune.py``),
  `sweep`, `curves` and `zoo` (``python -m capture_bench sweep | curves | zoo-hyperparams``);
* `features`, `seeds` and `callbacks`: paths that stored files name (the shipped models pickle
  `features`; the RL Zoo's ``configs/zoo/*.yml`` name `seeds` and `callbacks`).
"""
