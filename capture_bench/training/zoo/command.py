"""``python -m capture_bench zoo-hyperparams``: the RL Zoo's (rl_zoo3) hyper-parameter files,
made from ours.

``configs/zoo/<algo>.yml`` holds one entry per registered env ID (the key the Zoo looks an env
up by), each made from ``configs/algos/<algo>.yaml`` with that scenario's section applied,
exactly as ``train.py`` resolves it (`
resolve_hyperparameters`), so that::

    python -m rl_zoo3.train --algo ppo --env CaptureBench/Paper-v1 \\
        --gym-packages capture_bench --conf-file configs/zoo/ppo.yml

trains with our settings. What maps to what:

=========================  ====================================================================
ours                       the Zoo's entry
=========================  ====================================================================
``total_timesteps``        ``n_timesteps``
``n_envs``, ``policy``,    the same keys
``normalize``, the SB3
algorithm's keys
``learning_rate: lin_x``   the same: the Zoo's ``lin_`` schedule is ours (x times the progress
                           remaining)
``policy_kwargs``          a string the Zoo evaluates: ``activation_fn=nn.Tanh``, and the
                           features extractor as its class, imported in the string
``action_noise_std``       ``noise_type: normal``, ``noise_std``
``reward``                 ``env_kwargs: {reward: ...}``
training seeds only        ``env_wrapper``: `TrainingSeeds`
the curricula              ``callback``: our curriculum callbacks, with the scenario's final
                           tolerance or hold written in
the rollout statistics     ``callback``: `
                           RolloutMetrics`; ``monitor_kwargs`` puts ``is_success`` in the
                           Zoo's ``monitor.csv``
``checkpoint_freq``,       not file keys in the Zoo: its options ``--save-freq``,
``eval_freq``,             ``--eval-freq``, ``--eval-episodes`` (each entry's comment gives
``eval_episodes``          their values)
=========================  ====================================================================

A setting no Zoo entry can hold (a residual policy, pixel observations) is refused with one
line naming it. docs/training.md, "With the RL Zoo", says what the Zoo's runs lack.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import yaml

from capture_bench.argparsing import OneLineParser
from capture_bench.files import atomic_write, check_writable
from capture_bench.task.scenarios import (
    CONFIG_DIR,
    ConfigError,
    Scenario,
    list_scenarios,
    load_scenario,
)
from capture_bench.training.common.build import (
    check_curricula,
    check_shaping,
    curricula,
    fill_curriculum_steps,
)
from capture_bench.training.config.hyperparameters import (
    ACTIVATIONS,
    ALGO_KEYS,
    ALGORITHMS,
)
from capture_bench.training.config.settings import TrainingSettings, resolve_settings

PROG = "python -m capture_bench zoo-hyperparams"
ZOO_DIR = CONFIG_DIR / "zoo"
#: Our keys that the Zoo takes as command-line options, not file keys.
ZOO_OPTIONS = {
    "checkpoint_freq": "--save-freq",
    "eval_freq": "--eval-freq",
    "eval_episodes": "--eval-episodes",
}
#: The Zoo's Monitor records each episode's capture in ``monitor.csv`` (its ``is_success``).
MONITOR_KWARGS = "dict(info_keywords=('is_success',))"


def zoo_path(out: Path, algo: str) -> Path:
    """The Zoo file of ``algo`` in folder ``out``: ``<algo>.yml``."""
    return out / f"{algo}.yml"


def class_path(cls: type) -> str:
    """``module.Class``: how the Zoo names a wrapper or a callback."""
    return f"{cls.__module__}.{cls.__qualname__}"


def class_expression(cls: type) -> str:
    """A Python expression for ``cls`` that imports its module itself, for a string the Zoo
    evaluates (``__import__('a.b').b.C``)."""
    module = cls.__module__
    return f"__import__({module!r})." + ".".join([*module.split(".")[1:], cls.__qualname__])


def policy_kwargs_expression(policy_kwargs: dict[str, Any]) -> str:
    """Our validated ``policy_kwargs`` as the string the Zoo evaluates into SB3's (what
    `sb3_kwargs` makes): ``activation_fn`` as
    ``nn.<Name>`` (the Zoo's ``nn`` is ``torch.nn``), ``features_extractor`` as SB3's
    ``features_extractor_class``."""
    from capture_bench.agents.features import FEATURE_EXTRACTORS

    parts = []
    for key, value in policy_kwargs.items():
        if key == "activation_fn":
            parts.append(f"activation_fn=nn.{ACTIVATIONS[value]}")
        elif key == "features_extractor":
            parts.append(f"features_extractor_class={class_expression(FEATURE_EXTRACTORS[value])}")
        else:
            parts.append(f"{key}={_expression(value)}")
    return f"dict({', '.join(parts)})"


def _expression(value: Any) -> str:
    """A YAML value as Python source; a mapping as ``dict(k=v)``, which keeps the string free of
    the quotes and ``: `` that would make YAML quote it."""
    if isinstance(value, dict):
        return "dict(" + ", ".join(f"{k}={_expression(v)}" for k, v in value.items()) + ")"
    return repr(value)


def zoo_entry(settings: TrainingSettings, scenario: Scenario, source: str) -> dict[str, Any]:
    """One env ID's entry of the Zoo's file: ``settings`` (resolved for ``scenario``, read from
    ``source``) in the Zoo's keys (module docstring).

    Raises:
        ConfigError: ``settings`` holds a setting the Zoo's entry cannot carry.
    """
    from capture_bench.training import callbacks
    from capture_bench.training.seeds import TrainingSeeds

    if settings.residual != "none":
        raise ConfigError(
            f"{source}: residual {settings.residual!r} cannot go into an RL Zoo file: the policy "
            "acts through capture_bench's ResidualVecEnv, which needs the task's description, "
            "and the Zoo builds a vec env wrapper from keyword arguments only; train it with "
            "train.py, or set residual: none"
        )
    if settings.policy != "MlpPolicy" or settings.image_size is not None:
        raise ConfigError(
            f"{source}: pixel observations (policy {settings.policy}, image_size) cannot go into "
            "an RL Zoo file: the Zoo builds its evaluation env without the file's env_kwargs, "
            "so it would see the estimate; train pixels with train.py"
        )
    entry: dict[str, Any] = {
        "n_envs": settings.n_envs,
        "n_timesteps": settings.total_timesteps,
        "policy": settings.policy,
        "normalize": settings.normalize,
        "env_wrapper": class_path(TrainingSeeds),
        "env_kwargs": {"reward": settings.reward},
        "monitor_kwargs": MONITOR_KWARGS,
        "callback": [
            class_path(callbacks.RolloutMetrics),
            *(
                {class_path(getattr(callbacks, name)): kwargs}
                for name, kwargs in curricula(settings, scenario).items()
            ),
        ],
    }
    for key, value in settings.to_mapping().items():
        if key == "action_noise_std":
            if value:  # 0: no noise, as sb3_kwargs
                entry |= {"noise_type": "normal", "noise_std": value}
        elif key in ALGO_KEYS[settings.algo]:
            entry[key] = value
    if settings.policy_kwargs:
        entry["policy_kwargs"] = policy_kwargs_expression(dict(settings.policy_kwargs))
    return entry


def zoo_file(algo: str) -> str:
    """The text of ``configs/zoo/<algo>.yml``: a header, then per registered env ID a comment
    (the scenario, the section of ours it used, the Zoo options that take our checkpoint and
    validation settings) and its entry.

    Raises:
        ConfigError: an unknown algorithm, a bad hyper-parameter file, or a setting the Zoo
            cannot carry.
    """
    if algo not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {algo!r}; valid: {', '.join(ALGORITHMS)}")
    ours = f"configs/algos/{algo}.yaml"
    chunks = [
        f"# The RL Zoo's (rl_zoo3) hyper-parameters of capture-bench's {algo.upper()}: one entry "
        "per registered env ID,\n"
        f"# made from {ours} (and its scenario sections) by `{PROG}`.\n"
        "# Do not edit: tests/test_rl_zoo.py checks that this file is what the command makes.\n"
        f"#   python -m rl_zoo3.train --algo {algo} --env CaptureBench/Paper-v1 "
        "--gym-packages capture_bench \\\n"
        f"#       --conf-file configs/zoo/{algo}.yml --num-threads 1\n"
        '# What carries over and what does not: docs/training.md, "With the RL Zoo".\n'
    ]
    for name in list_scenarios():
        scenario = load_scenario(name)
        resolved, _, origin = resolve_settings(algo, scenario)
        source = ours + (f" (section {origin['section']})" if origin["section"] else "")
        settings = fill_curriculum_steps(resolved)
        check_shaping(settings.reward, settings.gamma)
        check_curricula(settings, scenario)
        entry = zoo_entry(settings, scenario, source)
        options = " ".join(f"{flag} {getattr(settings, key)}" for key, flag in ZOO_OPTIONS.items())
        chunks.append(f"\n# {name}: {source}; as the Zoo's options: {options}\n")
        chunks.append(
            yaml.safe_dump(  # width: no line folded inside a policy_kwargs string
                {scenario.env_id: entry}, sort_keys=False, default_flow_style=None, width=1000
            )
        )
    return "".join(chunks)


def build_parser() -> OneLineParser:
    parser = OneLineParser(
        prog=PROG,
        hint=" (see --help)",
        description="Write the RL Zoo's hyper-parameter files (<algo>.yml, one entry per "
        "registered env ID) from configs/algos/*.yaml, for python -m rl_zoo3.train "
        "--conf-file.",
    )
    parser.add_argument(
        "--algo",
        nargs="+",
        choices=ALGORITHMS,
        default=list(ALGORITHMS),
        help="the algorithms (default: all)",
    )
    parser.add_argument("--out", default=None, help=f"the folder to write to (default: {ZOO_DIR})")
    parser.add_argument(
        "--check",
        action="store_true",
        help="write nothing; exit 1 if a file in --out is missing or differs from what would "
        "be written",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """``python -m capture_bench zoo-hyperparams``; the exit status (0, 1: --check found a
    stale file, 2: a mistake, in one line)."""
    try:
        args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
        out = ZOO_DIR if args.out is None else Path(args.out)
        texts = {algo: zoo_file(algo) for algo in dict.fromkeys(args.algo)}  # all, then write
        if args.check:
            stale = [
                str(zoo_path(out, algo))
                for algo, text in texts.items()
                if not zoo_path(out, algo).is_file()
                or zoo_path(out, algo).read_text(encoding="utf-8") != text
            ]
            if stale:
                print(
                    f"zoo-hyperparams: not what configs/algos/ makes: {', '.join(stale)}; "
                    f"write them with {PROG}",
                    file=sys.stderr,
                )
                return 1
            print(f"zoo-hyperparams: {len(texts)} files in {out} are up to date")
            return 0
        check_writable(out, "--out")
        out.mkdir(parents=True, exist_ok=True)
        for algo, text in texts.items():
            atomic_write(zoo_path(out, algo), text.encode("utf-8"))
    except ConfigError as exc:
        print(f"zoo-hyperparams: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help (0) or a bad option (2, already printed in one line)
        return int(exc.code or 0)
    print(f"zoo-hyperparams: wrote {', '.join(str(zoo_path(out, a)) for a in texts)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
