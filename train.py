"""Train a Stable-Baselines3 policy on a capture-bench scenario.

    python train.py --algo ppo --scenario paper
    python train.py --algo sac --scenario paper --total-timesteps 200000 --seed 7
    python train.py --resume runs/paper-ppo-0 --total-timesteps 4000000
    tensorboard --logdir runs/paper-ppo-0/tb

The same command is installed as ``capture-bench-train``; it is
`capture_bench.training.train.command`. What a run does is in `capture_bench.training.common.run`
(options, hyper-parameters, checkpoints, the safe policy form).
"""

from __future__ import annotations

from script_entry import command_main, run

__all__ = ["main"]

PROG = "train.py"
COMMAND = "capture_bench.training.train.command:main"


def main(argv: list[str] | None = None) -> int:
    """Run the command (`capture_bench.training.train.command.main`); returns the exit status."""
    return command_main(COMMAND)(argv)


if __name__ == "__main__":
    raise SystemExit(run(PROG, COMMAND))
