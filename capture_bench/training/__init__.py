"""Training: hyper-parameter files, callbacks and checkpoints for ``train.py``."""
