"""The ``python -m capture_bench curves`` job: learning curves of several algorithms over training
seeds against incremental_ik's level (`command`), and rliable's statistics of the runs' final
validation scores with the training seed as the unit of replication (`seed_statistics`)."""
