"""``python -m capture_bench dataset``: record agents' episodes on a scenario's training or
validation seeds as a Minari dataset (``docs/datasets.md``).

Every bad input is one line on stderr and exit status 2: an unknown agent or scenario, a model
that observes pixels, a published evaluation seed or a seed outside the chosen set, a malformed
dataset id, a dataset that exists, an interrupted recording of the same id without
``--resume`` or with other options. Ctrl-C or SIGTERM keeps the finished episodes and says how
to resume (`capture_bench.datasets.recording`).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from capture_bench.agents.policy_file import PolicyLoadError
from capture_bench.argparsing import OneLineParser
from capture_bench.datasets.recording import (
    REPRODUCIBILITY,
    SEED_SETS,
    DatasetError,
    RecordingPlan,
    check_dataset_id,
    default_dataset_id,
    minari_root,
    prepare_staging,
    record,
    seed_range,
    staged,
)
from capture_bench.evaluation.errors import EvaluationError
from capture_bench.interrupts import exit_status
from capture_bench.progress import episode_bar
from capture_bench.task.scenarios import ConfigError

PROG = "python -m capture_bench dataset"


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=PROG,
        hint=" (see --help)",
        description="Record agents' episodes on a scenario's training (default) or validation "
        "seeds as a Minari dataset: observations, actions, rewards, terminations, truncations, "
        "info with the estimator's covariance (and the true target state with --privileged), "
        "the env's spec "
        "(dataset.recover_environment()) and each episode's seed. Published evaluation seeds "
        "are refused.",
    )
    parser.add_argument(
        "--agents",
        nargs="+",
        required=True,
        metavar="AGENT",
        help="agent specs, as evaluate.py takes them (a built-in name, oracle, a model "
        "directory such as models/dagger-dls-paper, module:Class), comma or space separated; "
        "several make a mixed dataset, every agent on every seed",
    )
    parser.add_argument(
        "--scenario", required=True, help="scenario name (python -m capture_bench list)"
    )
    parser.add_argument("--episodes", type=int, default=10, help="seeds per agent (default: 10)")
    parser.add_argument(
        "--seed-set",
        choices=SEED_SETS,
        default="training",
        help="the seeds to record: training (default) or validation; evaluation (the "
        "published seeds) is refused",
    )
    parser.add_argument(
        "--first-seed", type=int, help="the first seed (default: the seed set's first)"
    )
    parser.add_argument(
        "--id",
        dest="dataset_id",
        help="Minari dataset id (default: capture-bench/<scenario>/<agents>-v0)",
    )
    parser.add_argument(
        "--root",
        type=Path,
        help="Minari's datasets folder (default: $MINARI_DATASETS_PATH, else "
        "~/.minari/datasets); minari.load_dataset finds the dataset with "
        "MINARI_DATASETS_PATH set to it",
    )
    parser.add_argument(
        "--privileged",
        action="store_true",
        help="also record the true target state of every step (info true_target_position, "
        "true_target_velocity, true_target_rotation)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue an interrupted recording of the same id and options (its finished "
        "episodes are kept, the others played)",
    )
    parser.add_argument(
        "--trust-model",
        action="store_true",
        help="load a model directory that has only an SB3 .zip (unpickles it), as evaluate.py",
    )
    parser.add_argument("--description", help="the dataset's description (default: generated)")
    return parser


def _agents(specs: list[str], trust_model: bool) -> list[Any]:
    from capture_bench.evaluation.running.agents_loading import expand_specs, resolve_agent

    named = [item.strip() for spec in specs for item in spec.split(",") if item.strip()]
    resolved = [resolve_agent(s, trust_model=trust_model) for s in expand_specs(named)]
    for spec in resolved:
        if spec.image_size is not None:
            raise DatasetError(
                f"agent {spec.spec!r} observes the camera's pixels; datasets record the "
                "estimate's observation: name an agent that observes it"
            )
    return resolved


def _plan(args: argparse.Namespace, specs: list[Any]) -> RecordingPlan:
    from capture_bench.task.scenarios import load_scenario

    if args.episodes < 1:
        raise DatasetError(f"--episodes {args.episodes}: give 1 or more")
    scenario = load_scenario(args.scenario)
    seeds = seed_range(scenario, args.seed_set, args.first_seed, args.episodes)
    labels = tuple(s.label for s in specs)
    dataset_id = args.dataset_id or default_dataset_id(scenario.name, labels)
    return RecordingPlan(
        dataset_id=check_dataset_id(dataset_id),
        scenario=scenario.name,
        env_id=scenario.env_id,
        agents=tuple(s.spec for s in specs),
        labels=labels,
        seed_set=args.seed_set,
        first_seed=seeds.start,
        episodes=len(seeds),
        privileged=bool(args.privileged),
    )


def dataset_metadata(plan: RecordingPlan, specs: list[Any], description: str | None) -> dict:
    """The dataset's metadata beyond Minari's own: Minari's descriptive keys and, under
    ``capture_bench``, the code's version and the recording's plan."""
    from capture_bench import __version__
    from capture_bench.provenance import git_state, package_versions

    seeds = plan.seeds
    what = description or (
        f"{', '.join(plan.labels)} on capture-bench's {plan.scenario} scenario, {plan.seed_set} "
        f"seeds {seeds.start}-{seeds.stop - 1} (one episode per agent and seed), deterministic "
        "actions" + (", with the true target state" if plan.privileged else "")
    )
    return {
        "algorithm_name": "+".join(plan.labels),
        "author": {"capture-bench"},
        "description": what,
        "requirements": [f"capture-bench=={__version__}"],
        "capture_bench": {
            "version": __version__,
            "git": git_state(),
            "packages": package_versions(),
            **plan.to_json(),
            "privileged_agents": [s.label for s in specs if s.privileged],
            "command": f"{PROG} {shlex.join(sys.argv[2:])}"
            if sys.argv[1:2] == ["dataset"]
            else None,
            "reproducibility": REPRODUCIBILITY,
        },
    }


def _make_env(plan: RecordingPlan) -> Any:
    import gymnasium as gym

    import capture_bench  # noqa: F401  registers the envs

    return gym.make(plan.env_id)


def _check_agents(plan: RecordingPlan, specs: list[Any]) -> None:
    from capture_bench.evaluation.running.agents_loading import check_agent

    env = _make_env(plan)
    try:
        for spec in specs:
            check_agent(spec, env, plan.scenario)
    finally:
        env.close()


def _check_minari() -> None:
    try:
        import h5py  # noqa: F401
        import minari  # noqa: F401
    except ImportError as exc:
        raise DatasetError(
            f"datasets need minari with h5py ({exc.name} is not installed): pip install "
            "'capture-bench[datasets]' (or pip install 'minari[hdf5]>=0.5,<0.6')"
        ) from None


def run(args: argparse.Namespace) -> int:
    """Record the dataset the parsed command line asks for."""
    from capture_bench.evaluation.running.agents_loading import build_agent
    from capture_bench.files import check_writable

    _check_minari()
    root = (args.root or minari_root()).expanduser().resolve()
    specs = _agents(args.agents, args.trust_model)
    plan = _plan(args, specs)
    check_writable(root, "--root")
    os.environ["MINARI_DATASETS_PATH"] = str(root)  # Minari's namespaces are read from there
    _check_agents(plan, specs)
    staging = prepare_staging(plan, root, args.resume)
    start = time.perf_counter()
    bar, task = episode_bar(plan.dataset_id, len(plan.order()))
    try:
        with bar:
            folder = record(
                plan,
                root,
                staging,
                make_env=lambda: _make_env(plan),
                make_agent=lambda a, env, seed: build_agent(specs[a], env, seed),
                metadata=dataset_metadata(plan, specs, args.description),
                advance=lambda n: bar.advance(task, n),
            )
    except KeyboardInterrupt as exc:
        kept = len(staged(staging)) if staging.is_dir() else 0
        print(
            f"{PROG}: interrupted; {kept} of {len(plan.order())} episodes kept in {staging}: run "
            "the same command with --resume to continue",
            file=sys.stderr,
        )
        return exit_status(exc)
    _report(plan, folder, root, time.perf_counter() - start)
    return 0


def _report(plan: RecordingPlan, folder: Path, root: Path, seconds: float) -> None:
    import minari

    dataset = minari.load_dataset(plan.dataset_id)
    size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
    print(
        f"dataset {plan.dataset_id}: {dataset.total_episodes} episodes, {dataset.total_steps} "
        f"steps, {size / 1e6:.2f} MB, in {seconds:.1f} s: {folder}\n"
        f"load it with MINARI_DATASETS_PATH={root} and minari.load_dataset({plan.dataset_id!r})"
    )


def main(argv: list[str] | None = None) -> int:
    """Run the command; 0, 2 for bad input (one line), 130 or 143 when interrupted."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        return run(args)
    except (DatasetError, EvaluationError, ConfigError, PolicyLoadError) as exc:
        print(f"{PROG}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
