"""The options of ``tune.py``: one typed dataclass whose field docs are the ``--help``
(`TuneConfig`), and what they resolve to before any trial runs (`Setup`), which
the study, every trial and the outputs read."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from capture_bench.task.scenarios import Scenario
from capture_bench.training.config.hyperparameters import ALGORITHMS
from capture_bench.training.config.options import option as _opt


@dataclass
class TuneConfig:
    """The options of ``tune.py`` (None: from the base YAML, the scenario or the other options)."""

    algo: str = _opt("ppo", f"SB3 algorithm, one of {', '.join(ALGORITHMS)}")
    scenario: str = _opt("paper", "scenario name (configs/scenarios/<name>.yaml) or YAML path")
    config: str | None = _opt(
        None,
        "base hyper-parameter YAML the samples override, layered over configs/algos/<algo>.yaml "
        "as train.py layers it (default: that file alone)",
    )
    trials: int = _opt(20, "trials to run now, added to the study (0: only rewrite the outputs)")
    n_timesteps: int | None = _opt(
        None,
        "training budget of each trial, environment steps (default: a continued study's, else "
        "the YAML's total)",
    )
    n_evaluations: int = _opt(5, "validations per trial, evenly spaced; each is reported to Optuna")
    eval_episodes: int | None = _opt(
        None, "validation episodes (the scenario's first validation seeds; default: the YAML's)"
    )
    seed: int | None = _opt(
        None, "training seed of every trial, one of the scenario's training seeds (default: the "
        "first); the sampler draws trial n's parameters from a generator seeded with (this, n)"
    )  # fmt: skip
    n_startup_trials: int = _opt(
        5, "trials sampled at random before TPE models the results, and completed before the "
        "median pruner prunes"
    )  # fmt: skip
    keep: str | None = _opt(
        None, "comma-separated sampled parameters to keep at the base YAML's value instead "
        "(e.g. net_arch,batch_size)"
    )  # fmt: skip
    study_name: str | None = _opt(None, "Optuna study name (default: <scenario>-<algo>)")
    storage: str | None = _opt(
        None, "Optuna storage URL, any database URL Optuna accepts (default: "
        "sqlite:///<output>/study.db)"
    )  # fmt: skip
    output: str | None = _opt(None, "output directory (default: runs/tune-<scenario>-<algo>)")
    workers: int = _opt(
        1, "trials run at once, each in its own process with its share of --trials, all in one "
        "study (1: in this process)"
    )  # fmt: skip
    ray_address: str | None = _opt(
        None, "run the --workers as Ray tasks on the cluster at this address (HOST:PORT, auto, "
        "ray://HOST:PORT; local: a Ray instance started here), all in one --storage; needs Ray"
    )  # fmt: skip
    vec_env: str = _opt(
        "batched",
        "vectorisation of the training envs (as train.py)",
        ("batched", "dummy", "subproc"),
    )


@dataclass
class Setup:
    """A checked `TuneConfig`, resolved (`capture_bench.training.tune.command.prepare`):
    what every trial uses."""

    config: TuneConfig
    scenario: Scenario
    base: dict[str, Any]  # the validated base hyper-parameters
    base_path: Path
    given: set[str]  # the options given on the command line (the others may take a study's)
    budget: int  # environment steps per trial, all envs together
    every: int  # environment steps between validations
    eval_episodes: int
    keep: tuple[str, ...]
    study_name: str
    storage: str
    output: Path
    command: str = ""
