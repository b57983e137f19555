"""Tune an algorithm's hyper-parameters on a capture-bench scenario with Optuna.

    python tune.py --algo sac --scenario paper --trials 50 --n-timesteps 100000
    python tune.py --algo sac --scenario paper --trials 50        # 50 more, same study
    python tune.py --algo sac --scenario paper --trials 40 --workers 4   # 4 trials at a time
    python train.py --algo sac --config runs/tune-paper-sac/best.yaml

The same command is installed as ``capture-bench-tune`` (needs the ``tune`` extra:
``pip install 'capture-bench[tune]'``). Everything it does is in
`capture_bench.training.tune.command`.
"""

from __future__ import annotations

from script_entry import command_main, run

__all__ = ["main"]

PROG = "tune.py"
COMMAND = "capture_bench.training.tune.command:main"


def main(argv: list[str] | None = None) -> int:
    """Run the command (`capture_bench.training.tune.command.main`); returns the exit status."""
    return command_main(COMMAND)(argv)


if __name__ == "__main__":
    raise SystemExit(run(PROG, COMMAND))
