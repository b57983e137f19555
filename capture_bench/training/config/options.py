"""The options of ``train.py``: one typed dataclass whose field docs are the ``--help``."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass, field
from typing import Any

from capture_bench.argparsing import OneLineParser
from capture_bench.sensing.sources import ENV_OBSERVATIONS
from capture_bench.task.rewards import REWARD_MODES
from capture_bench.training.config.hyperparameters import ALGORITHMS


def option(default: Any, doc: str, choices: tuple[str, ...] | None = None) -> Any:
    """A dataclass field that is a command-line option: ``doc`` is its ``--help``."""
    return field(default=default, metadata={"doc": doc, "choices": choices})


_opt = option


@dataclass
class TrainConfig:
    """The options of ``train.py`` (None: take the value from the YAML file or the scenario)."""

    algo: str = _opt("ppo", f"SB3 algorithm, one of {', '.join(ALGORITHMS)}")
    scenario: str = _opt("paper", "scenario name (configs/scenarios/<name>.yaml) or YAML path")
    config: str | None = _opt(
        None,
        "hyper-parameter YAML layered over configs/algos/<algo>.yaml: the keys it sets replace "
        "the shipped ones, the others keep them",
    )
    total_timesteps: int | None = _opt(None, "environment steps to train for, in total (all envs)")
    n_envs: int | None = _opt(None, "parallel environments (default: the YAML's n_envs)")
    vec_env: str = _opt(
        "batched",
        "vectorisation: batched (the batched env, one process), or SB3's dummy (single envs, "
        "one process) or subproc (single envs, one process each)",
        ("batched", "dummy", "subproc"),
    )
    overrides: list[str] | None = _opt(
        None,
        "override one hyper-parameter, KEY=VALUE (VALUE in YAML; dotted keys reach into "
        "policy_kwargs: policy_kwargs.net_arch=[64,64]); repeat for more; checked like the file",
    )
    reward: str | None = _opt(
        None, f"reward: {', '.join(REWARD_MODES)} (default: the YAML's)", REWARD_MODES
    )
    seed: int | None = _opt(
        None, "seed; must be one of the scenario's training seeds (default: the first)"
    )
    observation_source: str | None = _opt(
        None,
        "what the agent sees: a target estimate (default: the scenario's), or pixels: the "
        "camera's image and the arm's state (with --config configs/pixels/<algo>.yaml)",
        ENV_OBSERVATIONS,
    )
    run_dir: str | None = _opt(
        None,
        "output directory (default: runs/<scenario>-<algo>-<seed>, or where that holds a run "
        "the first free runs/<scenario>-<algo>-<seed>_2, _3, ...)",
    )
    resume: str | None = _opt(
        None, "continue the run in this directory from its last checkpoint, with its saved config"
    )
    device: str = _opt(
        "cpu", "torch device (SB3 advises cpu for MLP policies)", ("auto", "cpu", "cuda")
    )


RESUMABLE_OPTIONS = ("total_timesteps", "vec_env", "device")


#: Options whose command-line name is not the field's.
FLAGS = {"overrides": "--set"}

EXAMPLES = """\
examples:
  python train.py --algo ppo --scenario paper
  python train.py --algo sac --scenario tumbling --total-timesteps 200000
  python train.py --algo tqc --set learning_rate=1.0e-3 --set policy_kwargs.net_arch=[64,64]
  python train.py --algo ppo --config runs/tune-paper-ppo/best.yaml --reward sparse
  python train.py --resume runs/paper-ppo-0 --total-timesteps 2000000
  tensorboard --logdir runs

algorithms: {algorithms} (configs/algos/<algo>.yaml; TQC from sb3-contrib)
scenarios:  {scenarios} (configs/scenarios/<name>.yaml, or a YAML path;
            all, or a,b,c: one policy on a mixture)
evaluate a run beside the built-in agents ({agents}),
on a suite or chosen scenarios (python evaluate.py --help lists the suites):
  python evaluate.py --agents incremental_ik runs/paper-ppo-0 --scenarios paper

A hyper-parameter YAML holds keys for every scenario and, optionally, per-scenario sections
(RL Zoo style) keyed by scenario name or env ID that override them. A --config file is layered
over configs/algos/<algo>.yaml (its keys replace the shipped ones, the others stay); --set
overrides both, then --n-envs, --total-timesteps and --reward. The resolved hyper-parameters are
saved in the run as hyperparameters.yaml (a --config file).
"""


def build_parser(prog: str = "train.py") -> argparse.ArgumentParser:
    """An argument parser generated from `TrainConfig` (each field's doc is its help),
    with examples and the valid algorithms and scenarios after the options."""
    from capture_bench.agents import AGENTS
    from capture_bench.task.scenarios import list_scenarios

    parser = OneLineParser(
        prog=prog,
        description="Train a Stable-Baselines3 policy on a scenario.",
        epilog=EXAMPLES.format(
            algorithms=", ".join(ALGORITHMS),
            scenarios=", ".join(list_scenarios()),
            agents=", ".join(sorted(AGENTS)),
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    for f in dataclasses.fields(TrainConfig):
        flag = FLAGS.get(f.name, "--" + f.name.replace("_", "-"))
        if f.name == "overrides":
            parser.add_argument(
                flag, action="append", dest=f.name, help=f.metadata["doc"], metavar="KEY=VALUE"
            )
            continue
        base = str if f.name in ("algo", "scenario") else f.type
        kind = int if "int" in str(base) else str
        doc = f.metadata["doc"] + (f" (default: {f.default})" if f.default is not None else "")
        parser.add_argument(
            flag,
            type=kind,
            default=None,  # None = not given, so --resume can tell what was asked for
            choices=f.metadata["choices"],
            help=doc,
            metavar=f.name.upper(),
        )
    return parser


def command_line(config: TrainConfig) -> str:
    """The ``train.py`` command that starts this run afresh (for model cards)."""
    words = ["python", "train.py"]
    for key, value in vars(config).items():
        if value is None or key in ("resume", "run_dir"):
            continue
        if key == "overrides":
            words += [f"--set {item}" for item in value]
        else:
            words.append(f"--{key.replace('_', '-')} {value}")
    return " ".join(words)


def parse_args(argv: list[str] | None) -> tuple[TrainConfig, set[str]]:
    """The options as a `TrainConfig` and the set of option names given explicitly."""
    namespace = build_parser().parse_args(argv)
    given = {k for k, v in vars(namespace).items() if v is not None}
    config = TrainConfig(**{k: v for k, v in vars(namespace).items() if v is not None})
    return config, given
