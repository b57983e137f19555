"""What ``tune.py`` does: search an algorithm's hyper-parameters with Optuna, as the RL Zoo does
(``rl_zoo3/exp_manager.py``: a seeded multivariate TPE sampler, a median pruner on the periodic
validations inside each trial), for the validation capture rate.

    python tune.py --algo sac --scenario paper --trials 50 --n-timesteps 100000
    python tune.py --algo sac --scenario paper --trials 50   # again: 50 more trials, same study
    python tune.py --algo sac --scenario paper --trials 40 --workers 4   # 4 trials at a time

Each trial trains ``--n-timesteps`` steps on training seeds only, with the hyper-parameters it
samples (`capture_bench.training.tune.search_spaces`) merged over those ``train.py`` would train
the scenario with (``configs/algos/<algo>.yaml`` and its scenario section, ``--config`` layered
over them) and validated like any config file, and is validated ``--n-evaluations`` times on
the first ``--eval-episodes`` validation seeds (never a published evaluation seed). The score of
a validation (`objective_value`) ranks the capture rate
first and, among equal capture rates, the median ratio of capture time to the physical limit
(lower is better). The options are `TuneConfig`.
Trials are stored in ``--storage`` (default ``sqlite:///<output>/study.db``); a study with the
same name is resumed with the settings it was created with
(`capture_bench.training.tune.study`: an option left out takes the study's value, another
value is refused). ``--workers N`` runs N trials at once in worker processes, ``--ray-address``
as Ray tasks on a cluster, and a second ``tune.py`` on the same study adds its trials to it
(`capture_bench.training.tune.workers`). At the end (also after Ctrl-C) ``--output`` gets
``best.yaml`` (for ``train.py --config``), ``trials.csv``, ``optimization_history.png`` and
``param_importances.png`` from every trial of the study, each written atomically. A user's
mistake is one line on stderr and exit 2, found before anything is written.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from capture_bench.argparsing import OneLineParser, program
from capture_bench.files import check_writable
from capture_bench.interrupts import exit_status, sigterm_as_interrupt
from capture_bench.ray_cluster import check_ray_cluster
from capture_bench.task.scenarios import ConfigError, load_scenario
from capture_bench.training.config.hyperparameters import (
    ALGORITHMS,
    OFF_POLICY,
    SB3_N_STEPS,
)
from capture_bench.training.config.settings import resolve_settings
from capture_bench.training.seeds import check_training_seed
from capture_bench.training.tune.options import Setup, TuneConfig
from capture_bench.training.tune.outputs import OUTPUT_FILES, redacted, write_outputs
from capture_bench.training.tune.search_spaces import SAMPLERS, Choice
from capture_bench.training.tune.storage import shared_url
from capture_bench.training.tune.study import keep_settings

PROG = program("tune.py")  # capture-bench-tune when run as that console script
INSTALL_HINT = "pip install 'capture-bench[tune]' (or: pip install 'optuna>=3.4')"


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """An argument parser generated from `TuneConfig` (each field's doc is its help)."""
    parser = OneLineParser(
        prog=prog, description="Tune an algorithm's hyper-parameters with Optuna."
    )
    for f in dataclasses.fields(TuneConfig):
        kind = int if "int" in str(f.type) else str
        doc = f.metadata["doc"] + (f" (default: {f.default})" if f.default is not None else "")
        parser.add_argument(
            "--" + f.name.replace("_", "-"),
            type=kind,
            default=None,  # None = not given: a continued study's own value may apply
            choices=f.metadata["choices"],
            help=doc,
            metavar=f.name.upper(),
        )
    return parser


def parse_args(argv: list[str] | None) -> tuple[TuneConfig, set[str]]:
    """The options as a `TuneConfig` and the set of option names given explicitly
    (argparse exits 2 on a bad option, in one line)."""
    namespace = build_parser().parse_args(argv)
    given = {k for k, v in vars(namespace).items() if v is not None}
    return TuneConfig(**{k: v for k, v in vars(namespace).items() if v is not None}), given


def _positive(value: int | None, option: str, low: int = 1) -> None:
    if value is not None and value < low:
        raise ConfigError(f"--{option} must be >= {low}, got {value}")


def prepare(config: TuneConfig, given: set[str] | None = None) -> Setup:
    """Check and resolve every option before any work; writes nothing. ``given``: the options
    given on the command line (default: none; the others may take a continued study's value,
    `open_study`). Raises [`ConfigError`][capture_bench.ConfigError] naming what is wrong."""
    from capture_bench.training.common.build import check_curricula, check_shaping

    config.algo = config.algo.lower()
    if config.algo not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {config.algo!r}; valid: {', '.join(ALGORITHMS)}")
    scenario = load_scenario(config.scenario)
    settings, base_path, _ = resolve_settings(config.algo, scenario, config.config)
    check_shaping(settings.reward, settings.gamma)
    check_curricula(settings, scenario)
    base = settings.to_mapping()
    if config.algo not in SAMPLERS:
        raise ConfigError(
            f"--algo {config.algo}: no search space for it in capture_bench/training/"
            f"search_spaces.py (SAMPLERS); algorithms with one: {', '.join(SAMPLERS)}"
        )
    if config.seed is None:
        config.seed = scenario.training_seeds.start
    check_training_seed(config.seed, scenario)
    for option in ("n_timesteps", "n_evaluations", "eval_episodes"):
        _positive(getattr(config, option), option.replace("_", "-"))
    _positive(config.trials, "trials", low=0)
    _positive(config.n_startup_trials, "n-startup-trials", low=0)
    _positive(config.workers, "workers")
    if config.ray_address is not None:
        check_ray_cluster(config.ray_address, "--ray-address")
    budget = config.n_timesteps or base["total_timesteps"]
    n_envs = base["n_envs"]
    every = budget // config.n_evaluations
    if every < n_envs:
        raise ConfigError(
            f"--n-timesteps {budget} is too small for --n-evaluations {config.n_evaluations}: "
            f"a validation follows at least one step of all {n_envs} envs, so the budget must "
            f"be >= {config.n_evaluations * n_envs}"
        )
    episodes = config.eval_episodes or base["eval_episodes"]
    available = len(scenario.validation_seeds)
    if episodes > available:
        raise ConfigError(
            f"--eval-episodes {episodes}: scenario {scenario.name!r} has {available} validation "
            f"seeds; use at most {available}"
        )
    space = SAMPLERS[config.algo]
    keep = tuple(name for name in (config.keep or "").split(",") if name)
    unknown = [name for name in keep if name not in space]
    if unknown:
        raise ConfigError(
            f"--keep {unknown[0]}: not a sampled parameter of {config.algo}; valid: "
            f"{', '.join(space)}"
        )
    output = Path(config.output or f"runs/tune-{scenario.name}-{config.algo}")
    check_writable(output, "--output")
    for name in OUTPUT_FILES:
        if (output / name).is_dir():
            raise ConfigError(f"--output {output}: {output / name} is a folder, not a file")
    storage = config.storage or f"sqlite:///{output / 'study.db'}"
    if config.workers > 1 or config.ray_address is not None:
        _check_shared(storage)
    setup = Setup(
        config=config,
        scenario=scenario,
        base=base,
        base_path=base_path,
        given=set(given or ()),
        budget=budget,
        every=every,
        eval_episodes=episodes,
        keep=keep,
        study_name=config.study_name or f"{scenario.name}-{config.algo}",
        storage=storage,
        output=output,
    )
    setup.command = study_command(setup)
    return setup


def _check_shared(storage: str) -> None:
    """Refuse a storage that worker processes cannot share (SQLite in memory)."""
    try:
        shared = shared_url(storage)
    except Exception:  # a malformed URL: open_study says what is wrong with it
        return
    if shared is None:
        raise ConfigError(
            f"--storage {redacted(storage)}: a SQLite database in memory is private to one "
            "process; --workers and --ray-address need a storage the workers share, e.g. "
            "sqlite:///<file> or a database server's URL"
        )


def study_command(setup: Setup) -> str:
    """The ``tune.py`` command of the study's trials: every setting that defines a trial
    (`SETTINGS`) spelled out, and where the study is."""
    config = setup.config
    words = ["python", "tune.py", "--algo", config.algo, "--scenario", config.scenario]
    if config.config:
        words += ["--config", str(config.config)]
    words += ["--n-timesteps", str(setup.budget), "--n-evaluations", str(config.n_evaluations)]
    words += ["--eval-episodes", str(setup.eval_episodes), "--seed", str(config.seed)]
    if setup.keep:
        words += ["--keep", ",".join(setup.keep)]
    for option, value in (("study-name", config.study_name), ("storage", config.storage),
                          ("output", config.output)):  # fmt: skip
        if value is not None:
            words += [f"--{option}", redacted(str(value))]
    return " ".join(words)


def _note_rollouts(setup: Setup) -> None:
    """Say where an on-policy trial can validate before its first update: PPO learns after
    whole rollouts of ``n_steps x n_envs`` steps, which may exceed the validation spacing."""
    if setup.config.algo in OFF_POLICY:
        return
    param = SAMPLERS[setup.config.algo].get("n_steps")
    if param is not None and "n_steps" not in setup.keep and isinstance(param.space, Choice):
        n_steps = max(param.space.values)
    else:
        n_steps = setup.base.get("n_steps", SB3_N_STEPS[setup.config.algo])
    rollout = n_steps * setup.base["n_envs"]
    if rollout > setup.every:
        print(
            f"note: {setup.config.algo.upper()} updates after whole rollouts of up to "
            f"{rollout} steps (n_steps {n_steps} x {setup.base['n_envs']} envs), more than the "
            f"{setup.every} steps between validations: such trials validate before they learn; "
            "raise --n-timesteps, or --keep n_steps with a smaller one in --config"
        )


def open_study(setup: Setup) -> Any:
    """Create the study in ``setup.storage``, or load the one of that name: then its algorithm and
    scenario must match, and ``setup`` takes the settings its trials ran with, or a differing
    option is refused (`keep_settings`). The study
    samples and prunes as `sampler` says (trial n's random
    numbers seeded with ``(--seed, n)``)."""
    import optuna

    from capture_bench.training.tune.sampler import configure
    from capture_bench.training.tune.storage import open_storage

    config = setup.config
    try:
        study = optuna.create_study(
            storage=open_storage(setup.storage),
            study_name=setup.study_name,
            direction="maximize",
            load_if_exists=True,
        )
    except Exception as exc:  # Optuna and SQLAlchemy raise many kinds on a bad URL
        raise ConfigError(f"--storage {redacted(setup.storage)}: {exc}") from None
    found = {key: study.user_attrs.get(key) for key in ("algo", "scenario")}
    wanted = {"algo": config.algo, "scenario": setup.scenario.name}
    if all(value is None for value in found.values()):
        for key, value in wanted.items():
            study.set_user_attr(key, value)
    elif found != wanted:
        raise ConfigError(
            f"--study-name {setup.study_name}: the study in {redacted(setup.storage)} tunes "
            f"{found['algo']} on {found['scenario']}, not {config.algo} on {setup.scenario.name}; "
            "choose another --study-name"
        )
    keep_settings(study, setup, setup.given)
    setup.command = study_command(setup)
    return configure(study, config)


def main(argv: list[str] | None = None) -> int:
    """Run ``tune.py`` with ``argv`` (default: ``sys.argv[1:]``); return the exit status."""
    try:
        config, given = parse_args(argv)
    except SystemExit as exc:  # --help (0) or a bad option (2, already printed)
        return int(exc.code or 0)
    try:
        import optuna  # noqa: F401  (only to say how to install it)
    except ImportError:
        print(f"{PROG}: error: tuning needs Optuna; install it: {INSTALL_HINT}", file=sys.stderr)
        return 2
    try:
        setup = prepare(config, given)
        setup.output.mkdir(parents=True, exist_ok=True)
        study = open_study(setup)
    except (ConfigError, OSError) as exc:
        print(f"{PROG}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    _note_rollouts(setup)
    _note_workers(setup)
    from capture_bench.training.tune.workers import run_study

    print(
        f"tuning {setup.config.algo.upper()} on {setup.scenario.name}: study {setup.study_name!r} "
        f"({len(study.trials)} trials so far), {setup.config.trials} more of {setup.budget} steps, "
        f"{setup.config.n_evaluations} validations of {setup.eval_episodes} episodes each"
        f"{_where(setup)} -> {setup.output}"
    )
    with sigterm_as_interrupt():
        interrupt, failures = run_study(study, setup)
        if interrupt is not None:
            print("\ninterrupted: the running trials are recorded as failed; writing the results "
                  "of the finished trials", file=sys.stderr)  # fmt: skip
        for failure in failures:
            print(f"{PROG}: error: {failure}", file=sys.stderr)
        try:
            write_outputs(study, setup)
        except KeyboardInterrupt as exc:  # a second Ctrl-C: each file is whole or absent
            return exit_status(exc)
    if interrupt is not None:
        return exit_status(interrupt)
    return 1 if failures else 0


def _where(setup: Setup) -> str:
    """Where the trials run, as the start line says it (nothing: in this process)."""
    config = setup.config
    workers = min(config.workers, config.trials)
    if workers == 0:
        return ""
    if config.ray_address is not None:
        return f", {workers} at a time as Ray tasks ({config.ray_address})"
    return f", {workers} at a time in worker processes" if workers > 1 else ""


def _note_workers(setup: Setup) -> None:
    """Say that a SQLite file serves one machine where the workers may run on several."""
    address = setup.config.ray_address
    if address not in (None, "local") and setup.storage.startswith("sqlite"):
        print(
            f"note: --storage {redacted(setup.storage)} is a file on this machine: Ray workers "
            "on other machines cannot reach it; give a database server's URL "
            "(postgresql://..., mysql://...) for a cluster of several machines"
        )
