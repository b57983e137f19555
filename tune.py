"""Tune an algorithm's hyper-parameters on a capture-bench scenario with Optuna.

    python tune.py --algo sac --scenario paper --trials 50 --n-timesteps 100000
    python tune.py --algo sac --scenario paper --trials 50        # 50 more, same study
    python tune.py --algo sac --scenario paper --trials 40 --workers 4   # 4 trials at a time
    python train.py --algo sac --config runs/tune-paper-sac/best.yaml

The same command is installed as ``capture-bench-tune`` (needs the ``tune`` extra:
``pip install 'capture-bench[tune]'``). Everything it does is in
:mod:`capture_bench.training.tune`.
"""

from __future__ import annotations

import sys

from capture_bench.training.tune import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
