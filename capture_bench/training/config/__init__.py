"""Training configuration: the hyper-parameter files (``configs/algos/*.yaml``, their keys, bounds
and layering: `hyperparameters`), a run's validated hyper-parameters as one frozen object
(`settings`), and ``train.py``'s typed options (`options`), which every training job reads and
none of them owns."""
