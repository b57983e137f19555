"""Behaviour cloning from a Minari dataset: a policy of a shipped model's shape fitted to the
dataset's (observation, action) pairs, written as a model directory that ``evaluate.py`` loads
like any model (``policy.pt`` + ``metadata.json``, the safe form).

The network is the ``--like`` model's (default ``models/dagger-dls-paper``: PPO, 128 x 128
tanh, the ``relative_log_distance`` features), freshly initialised; its mean action is fitted to
the recorded actions by the imitation fit ``train.py``'s DAgger uses
(`capture_bench.training.common.imitation.fit`: squared error, Adam, minibatches of 1024,
``--epochs`` passes). Unlike DAgger it never acts while it learns: it sees the states the
recorded agents visited, nothing else (offline). ``--agent`` keeps the episodes of one agent of a
mixed dataset, ``--captured-only`` the episodes that captured.

    python -m capture_bench dataset --agents planned_intercept --scenario paper --episodes 1000 \\
        --id capture-bench/paper/planned_intercept-v0
    python scripts/bc_from_dataset.py --dataset capture-bench/paper/planned_intercept-v0 \\
        --out runs/bc-planned-intercept-paper
    python evaluate.py --agents runs/bc-planned-intercept-paper --scenarios paper --episodes 50 \\
        --seed-set validation --workers 1 --out /tmp/bc-eval
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from capture_bench.agents.policy_file import build_policy, save_policy
from capture_bench.agents.sb3_policy import read_metadata, read_metadata_file
from capture_bench.provenance import git_state, package_versions
from capture_bench.training.common.imitation import fit

DEFAULT_LIKE = "models/dagger-dls-paper"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True, help="Minari dataset id")
    parser.add_argument("--root", type=Path, help="Minari's datasets folder (MINARI_DATASETS_PATH)")
    parser.add_argument("--out", type=Path, required=True, help="the model directory to write")
    parser.add_argument("--like", default=DEFAULT_LIKE, help="the model whose network to copy")
    parser.add_argument("--agent", help="keep the episodes of this agent only (its label)")
    parser.add_argument("--captured-only", action="store_true", help="keep captures only")
    parser.add_argument("--epochs", type=int, default=200, help="passes of the fit (200)")
    parser.add_argument("--seed", type=int, default=0, help="the fit's seed (minibatch order)")
    return parser.parse_args(argv)


def pairs(
    dataset: Any, agent: str | None, captured_only: bool
) -> tuple[np.ndarray, np.ndarray, list]:
    """The (observation, action) pairs of the kept episodes, and the kept episodes' metadata."""
    metadata = list(dataset.storage.get_episode_metadata(range(dataset.total_episodes)))
    observations, actions, kept = [], [], []
    for episode, meta in zip(dataset.iterate_episodes(), metadata):
        if agent is not None and meta.get("agent") != agent:
            continue
        if captured_only and meta.get("outcome") != "captured":
            continue
        observations.append(episode.observations[:-1])  # the observation each action answered
        actions.append(episode.actions)
        kept.append(meta)
    if not kept:
        raise SystemExit(f"bc_from_dataset.py: no episode of {dataset.id} is kept by the filters")
    return np.concatenate(observations), np.concatenate(actions), kept


def _card(args: argparse.Namespace, dataset: Any, kept: list, rows: int, loss: float,
          seconds: float) -> dict[str, Any]:  # fmt: skip
    ours = dataset.storage.metadata.get("capture_bench", {})
    return {
        "method": "behaviour cloning (offline: the fit sees only the dataset's states)",
        "dataset": dataset.id,
        "dataset_code": {"version": ours.get("version"), "git": ours.get("git")},
        "agents": sorted({str(m.get("agent")) for m in kept}),
        "episodes": len(kept),
        "dataset_seeds": sorted({int(m["seed"]) for m in kept}),
        "seed_set": ours.get("seed_set"),
        "pairs": rows,
        "epochs": args.epochs,
        "fit_seed": args.seed,
        "fit_mse": loss,
        "network_like": args.like,
        "wall_time_s": round(seconds, 1),
        "actions": "deterministic",
    }


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.root is not None:
        os.environ["MINARI_DATASETS_PATH"] = str(args.root)
    import minari
    import torch

    torch.set_num_threads(1)
    dataset = minari.load_dataset(args.dataset)
    observations, actions, kept = pairs(dataset, args.agent, args.captured_only)
    like = read_metadata(args.like)
    assert like.declaration is not None, f"{args.like}: needs the safe form (policy.pt)"
    torch.manual_seed(args.seed)
    policy = build_policy(like.declaration, str(like.metadata_file))
    start = time.perf_counter()
    loss = fit(policy, observations, actions, args.epochs, args.seed)
    seconds = time.perf_counter() - start
    ours = dataset.storage.metadata.get("capture_bench", {})
    source = read_metadata_file(like.metadata_file)
    extra = {
        "scenario": ours.get("scenario", source.get("scenario")),
        "env_id": dataset.env_spec.id if dataset.env_spec else source.get("env_id"),
        "observation_source": "ekf",
        "reward": source.get("reward", "dense"),
        "residual": None,
        "command": "python scripts/bc_from_dataset.py "
        + shlex.join(sys.argv[1:] if argv is None else argv),
        "git": git_state(),
        "packages": package_versions(),
        "model_card": _card(args, dataset, kept, len(observations), loss, seconds),
    }
    save_policy(args.out, like.algorithm, policy, like.declaration.normalization, extra)
    print(
        f"{args.out}: {len(kept)} episodes, {len(observations)} pairs, {args.epochs} epochs, "
        f"fit MSE {loss:.2e}, {seconds:.0f} s"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
