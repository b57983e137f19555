"""Offline datasets: an agent's episodes on a scenario's training or validation seeds as a Minari
dataset (``python -m capture_bench dataset``, `capture_bench.datasets.command`).

`capture_bench.datasets.episodes` plays one episode and holds its arrays (observations, actions,
rewards, terminations, truncations, ``info`` with the estimator's covariance, and with
``privileged`` the true target state);
`capture_bench.datasets.recording` stages finished episodes one file each, so an interrupted
recording resumes without repeating or duplicating one, and writes the Minari dataset when every
episode is there. ``docs/datasets.md`` says what a dataset holds.
"""
