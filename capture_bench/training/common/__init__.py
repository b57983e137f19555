"""What the training jobs share: one training run from options to saved policy (`run`, which
``train.py`` is and which the sweep's tasks and ``curves --train`` call), the envs, model and
curricula it builds and the option checks it makes (`build`), the vector envs (`sb3_vec_env`,
`residual_vec_env`, `mixture`), checkpoints, the run lock, imitation, validation and its
statistics (`validation_run`, `episode_stats`), the policy's safe export and the plan of named
runs under one root (`run_plan`). The jobs import these, never each other."""
