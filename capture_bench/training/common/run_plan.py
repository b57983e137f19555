"""Runs of train.py named by what they train, under one root: where each lives, whether it is
finished or can be resumed, and the train.py command line that trains or resumes it. Shared by
``python -m capture_bench curves --train`` and ``python -m capture_bench sweep``.

A run of the algorithm ``algo`` on ``scenario`` from training seed ``seed`` is
``<root>/<scenario>-<arm>-<seed>``, where the arm is the algorithm (``ppo``) or the algorithm on
the camera's pixels (``ppo-pixels``: ``--observation-source pixels --config
configs/pixels/ppo.yaml``). A run is finished once it holds ``metadata.json`` (train.py writes it
last); it can be resumed from its newest checkpoint (``checkpoints/step_<N>/``).
"""

from __future__ import annotations

from pathlib import Path

from capture_bench.task.scenarios import ConfigError
from capture_bench.training.common.checkpoint import list_checkpoints

#: An arm ``<algo>-pixels``: ``<algo>`` trained on the camera's pixels.
PIXEL_ARM = "-pixels"
#: The file train.py writes last: a run that holds it is finished.
FINISHED_FILE = "metadata.json"


def run_path(runs: Path, scenario: str, arm: str, seed: int) -> Path:
    """``<runs>/<scenario>-<arm>-<seed>``."""
    return Path(runs) / f"{scenario}-{arm}-{seed}"


def arm_options(arm: str) -> tuple[str, list[str]]:
    """The algorithm of an arm (``ppo``, or ``ppo-pixels``) and the train.py options it adds."""
    if not arm.endswith(PIXEL_ARM):
        return arm, []
    from capture_bench.training.common.build import pixel_config

    algo = arm.removesuffix(PIXEL_ARM)
    return algo, ["--observation-source", "pixels", "--config", str(pixel_config(algo))]


def arms(algos: list[str], pixels: bool) -> list[str]:
    """The arms of ``algos``: each algorithm, then (``pixels``) each on pixels.

    Raises:
        ConfigError: ``pixels`` for an algorithm without pixel hyper-parameters.
    """
    found = list(dict.fromkeys(algos))
    for algo in found if pixels else []:
        _, options = arm_options(algo + PIXEL_ARM)
        if not Path(options[-1]).is_file():
            raise ConfigError(
                f"--pixels: {algo} has no pixel hyper-parameters ({options[-1]} is missing); "
                "ppo has configs/pixels/ppo.yaml"
            )
    return found + [algo + PIXEL_ARM for algo in found if pixels]


def is_finished(run_dir: Path) -> bool:
    """The run has written its final policy (``metadata.json``)."""
    return (Path(run_dir) / FINISHED_FILE).is_file()


def resumable_step(run_dir: Path) -> int | None:
    """The step of the run's newest complete checkpoint, or None where it has none."""
    found = list_checkpoints(Path(run_dir) / "checkpoints")
    return found[-1][0] if found else None


def train_argv(
    run_dir: Path,
    scenario: str,
    arm: str,
    seed: int,
    resume: bool,
    extra: list[str] | None = None,
) -> list[str]:
    """train.py's command line for the run in ``run_dir``: ``--resume run_dir``, or a new run of
    the arm's algorithm (and options) on ``scenario`` from ``seed`` into ``run_dir``; ``extra``
    (train.py options) appended to a new run's."""
    if resume:
        return ["--resume", str(run_dir)]
    algo, options = arm_options(arm)
    return [
        "--algo", algo, "--scenario", scenario, "--seed", str(seed), "--run-dir", str(run_dir),
        *options, *(extra or []),
    ]  # fmt: skip
