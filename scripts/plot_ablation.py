"""Plot an ablation: validation capture rate and median ratio to the physical limit against
environment steps for several train.py runs (their ``validations.csv``), one line each.

    python scripts/plot_ablation.py --out docs/figures/ablation_ppo_paper.png \
        dense=runs/ablation/dense features=runs/ablation/features ...

The runs of README's "Learning the last millimetre" were made with (at commit 0cde12e):

    python train.py --algo ppo --scenario paper --total-timesteps 300000 --set eval_freq=30000 \
        --set eval_episodes=20 --set checkpoint_freq=100000 --run-dir runs/ablation/<name> <lever>

with <lever> empty (dense), ``--reward shaped``, ``--set
policy_kwargs.features_extractor=relative_log_distance``, or both.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="label=run_dir")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    for item in args.runs:
        label, _, directory = item.partition("=")
        with open(Path(directory) / "validations.csv") as handle:
            rows = list(csv.DictReader(handle))
        steps = [int(r["step"]) for r in rows]
        axes[0].plot(steps, [float(r["capture_rate"]) for r in rows], marker="o", label=label)
        axes[1].plot(steps, [float(r["median_ratio_to_limit"]) for r in rows], marker="o")
    axes[0].set_ylabel("validation capture rate")
    axes[1].set_ylabel("median ratio to the physical limit")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.savefig(args.out, dpi=100)
    print(args.out)


if __name__ == "__main__":
    main()
