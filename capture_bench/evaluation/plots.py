"""Report figures as PNG bytes (matplotlib, Agg backend, imported lazily).

* survival curves per scenario: Kaplan-Meier share of episodes not yet captured vs time, s, with
  the 95% band; failures are censored at the time their episode ended;
* failures by reason: per scenario, each agent's episodes split into captured and each reason;
* ratio to the physical limit: per scenario, the distribution of capture time / bound per agent;
* one episode: distance, estimate error and actions vs time (``--episode-plots``).
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from capture_bench.evaluation.aggregate import Summary
from capture_bench.evaluation.rollout import EpisodeRecord, EpisodeTrace

DPI = 90
OUTCOME_COLOURS = {
    "captured": "tab:green",
    "timeout": "tab:gray",
    "collision": "tab:red",
    "target_lost": "tab:orange",
    "unreachable": "tab:purple",
}


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _horizontal() -> dict[str, Any]:
    """Horizontal box plots across matplotlib versions (``vert`` is deprecated from 3.10)."""
    import matplotlib

    major, minor = (int(p) for p in matplotlib.__version__.split(".")[:2])
    return {"orientation": "horizontal"} if (major, minor) >= (3, 10) else {"vert": False}


def _png(fig: Any) -> bytes:
    buffer = io.BytesIO()
    # metadata={"Software": None} keeps the bytes independent of the matplotlib version string
    fig.savefig(buffer, format="png", dpi=DPI, bbox_inches="tight", metadata={"Software": None})
    _pyplot().close(fig)
    return buffer.getvalue()


def _grid(n: int, width: float = 5.0, height: float = 3.2) -> tuple[Any, list[Any]]:
    plt = _pyplot()
    cols = 1 if n == 1 else 2
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(width * cols, height * rows), squeeze=False)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


def survival_figure(scenario: str, summaries: Sequence[Summary]) -> bytes:
    """Kaplan-Meier curves of every agent on one scenario."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for s in summaries:
        c = s.survival
        (line,) = ax.step(c.time, c.survival, where="post", label=s.agent)
        ax.fill_between(c.time, c.low, c.high, step="post", alpha=0.15, color=line.get_color())
    ax.set_xlabel("time since episode start, s")
    ax.set_ylabel("share of episodes not yet captured")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(f"{scenario}: time to capture (Kaplan-Meier, failures censored)")
    ax.legend(fontsize="small", loc="lower left")
    ax.grid(alpha=0.3)
    return _png(fig)


def failures_figure(summaries: Sequence[Summary], reasons: Sequence[str]) -> bytes:
    """Stacked shares of outcomes (captured, then each failure reason) per agent and scenario."""
    scenarios = list(dict.fromkeys(s.scenario for s in summaries))
    fig, axes = _grid(len(scenarios))
    for ax, scenario in zip(axes, scenarios):
        cells = [s for s in summaries if s.scenario == scenario]
        names = [s.agent for s in cells]
        left = np.zeros(len(cells))
        for label in ["captured", *reasons]:
            counts = np.array(
                [(s.captured if label == "captured" else s.failures.get(label, 0)) for s in cells]
            )
            share = counts / np.array([s.episodes for s in cells])
            ax.barh(names, share, left=left, label=label, color=OUTCOME_COLOURS.get(label))
            left += share
        ax.set_xlim(0, 1)
        ax.set_xlabel("share of episodes")
        ax.set_title(scenario)
        ax.invert_yaxis()
    fig.suptitle("Outcomes: captured, or the failure reason")
    fig.tight_layout()
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), bbox_to_anchor=(0.5, 0.0))
    return _png(fig)


def ratio_figure(records: Sequence[EpisodeRecord]) -> bytes:
    """Distribution of capture time / physical-limit time per agent, one panel per scenario."""
    scenarios = list(dict.fromkeys(r.scenario for r in records))
    agents = list(dict.fromkeys(r.agent for r in records))
    fig, axes = _grid(len(scenarios))
    for ax, scenario in zip(axes, scenarios):
        data, names = [], []
        for agent in agents:
            ratios = [
                r.ratio
                for r in records
                if r.scenario == scenario and r.agent == agent and np.isfinite(r.ratio)
            ]
            if ratios:
                data.append(ratios)
                names.append(agent)
        if data:
            ax.boxplot(data, showfliers=True, **_horizontal())
            ax.set_yticks(range(1, len(names) + 1), names)
            ax.invert_yaxis()
        else:
            ax.text(0.5, 0.5, "no capture", ha="center", va="center", transform=ax.transAxes)
        ax.axvline(1.0, color="k", lw=0.8, ls="--")
        ax.set_xlabel("capture time / physical limit")
        ax.set_title(scenario)
    fig.suptitle("Ratio to the physical limit (captured episodes; 1 = the bound)")
    fig.tight_layout()
    return _png(fig)


def episode_figure(record: EpisodeRecord, trace: EpisodeTrace) -> bytes:
    """Distance to the target, estimate error and actions over one episode."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(6.4, 6.4), sharex=True)
    axes[0].semilogy(trace.time, np.maximum(trace.distance, 1e-6))
    axes[0].set_ylabel("distance, m")
    axes[1].plot(trace.time, trace.position_error * 1e3)
    axes[1].set_ylabel("estimate error, mm")
    for j in range(trace.action.shape[1]):
        axes[2].plot(trace.time, trace.action[:, j], label=f"joint {j + 1}")
    axes[2].set_ylabel("action")
    axes[2].set_xlabel("time, s")
    axes[2].legend(fontsize="small")
    outcome = record.outcome if record.captured else f"failed: {record.failure}"
    axes[0].set_title(f"{record.agent} on {record.scenario}, seed {record.seed} ({outcome})")
    for ax in axes:
        ax.grid(alpha=0.3)
    return _png(fig)
