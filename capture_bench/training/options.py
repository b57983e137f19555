"""The options of ``train.py``: one typed dataclass whose field docs are the ``--help``."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass, field
from typing import Any

from capture_bench.argparsing import OneLineParser
from capture_bench.task.scenarios import OBSERVATION_SOURCES
from capture_bench.training.hyperparameters import ALGORITHMS


def _opt(default: Any, doc: str, choices: tuple[str, ...] | None = None) -> Any:
    return field(default=default, metadata={"doc": doc, "choices": choices})


@dataclass
class TrainConfig:
    """The options of ``train.py`` (None: take the value from the YAML file or the scenario)."""

    algo: str = _opt("ppo", f"SB3 algorithm, one of {', '.join(ALGORITHMS)}")
    scenario: str = _opt("paper", "scenario name (configs/scenarios/<name>.yaml) or YAML path")
    config: str | None = _opt(None, "hyper-parameter YAML (default: configs/algos/<algo>.yaml)")
    total_timesteps: int | None = _opt(None, "environment steps to train for, in total (all envs)")
    n_envs: int | None = _opt(None, "parallel environments (default: the YAML's n_envs)")
    vec_env: str = _opt(
        "batched",
        "vectorisation: batched (the batched env, one process), or SB3's dummy (single envs, "
        "one process) or subproc (single envs, one process each)",
        ("batched", "dummy", "subproc"),
    )
    seed: int | None = _opt(
        None, "seed; must be one of the scenario's training seeds (default: the first)"
    )
    observation_source: str | None = _opt(
        None, "target estimate the agent sees (default: the scenario's)", OBSERVATION_SOURCES
    )
    run_dir: str | None = _opt(None, "output directory (default: runs/<scenario>-<algo>-<seed>)")
    resume: str | None = _opt(
        None, "continue the run in this directory from its last checkpoint, with its saved config"
    )
    device: str = _opt(
        "cpu", "torch device (SB3 advises cpu for MLP policies)", ("auto", "cpu", "cuda")
    )


RESUMABLE_OPTIONS = ("total_timesteps", "vec_env", "device")


def build_parser(prog: str = "train.py") -> argparse.ArgumentParser:
    """An argument parser generated from :class:`TrainConfig` (each field's doc is its help)."""
    parser = OneLineParser(prog=prog, description="Train a Stable-Baselines3 policy on a scenario.")
    for f in dataclasses.fields(TrainConfig):
        base = str if f.name in ("algo", "scenario") else f.type
        kind = int if "int" in str(base) else str
        doc = f.metadata["doc"] + (f" (default: {f.default})" if f.default is not None else "")
        parser.add_argument(
            "--" + f.name.replace("_", "-"),
            type=kind,
            default=None,  # None = not given, so --resume can tell what was asked for
            choices=f.metadata["choices"],
            help=doc,
            metavar=f.name.upper(),
        )
    return parser


def parse_args(argv: list[str] | None) -> tuple[TrainConfig, set[str]]:
    """The options as a :class:`TrainConfig` and the set of option names given explicitly."""
    namespace = build_parser().parse_args(argv)
    given = {k for k, v in vars(namespace).items() if v is not None}
    config = TrainConfig(**{k: v for k, v in vars(namespace).items() if v is not None})
    return config, given
