"""Report figures as PNG bytes (matplotlib, Agg backend, imported lazily).

* survival curves per scenario: Kaplan-Meier share of episodes not yet captured vs time, s, with
  the 95% band; failures are censored at the time their episode ended;
* failures by reason: per scenario, each agent's episodes split into captured and each reason;
* ratio to the physical limit: per scenario, the distribution of capture time / bound per agent;
* one episode: distance, estimate error and actions vs time (``--episode-plots``);
* the summary (`capture_bench.evaluation.summary`): the agent x scenario heatmap, the
  ranking with intervals, the probability-of-improvement matrix;
* rliable's performance profiles (`capture_bench.evaluation.rliable_report`).

Every agent has one colour in every figure (`agent_colours`: the Okabe-Ito colour-blind-safe
palette in the agents' order), and the reference agent (the paper's controller) is drawn black
and thicker.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from capture_bench import rliable_stats
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


#: Okabe & Ito's colour-blind-safe palette (without black, kept for the reference), then more.
PALETTE = ("#E69F00", "#56B4E9", "#009E73", "#0072B2", "#D55E00", "#CC79A7", "#F0E442",
           "#999999", "#882255", "#44AA99", "#117733", "#332288")  # fmt: skip
REFERENCE_COLOUR = "#000000"


def agent_colours(agents: Sequence[str], reference: str | None = None) -> dict[str, str]:
    """One colour per agent, the same in every figure of a report: the reference black, the
    others the palette in order (cycling past its end)."""
    others = [a for a in agents if a != reference]
    colours = {a: PALETTE[i % len(PALETTE)] for i, a in enumerate(others)}
    if reference is not None and reference in agents:
        colours[reference] = REFERENCE_COLOUR
    return colours


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


def survival_figure(
    scenario: str,
    summaries: Sequence[Summary],
    colours: dict[str, str] | None = None,
    reference: str | None = None,
) -> bytes:
    """Kaplan-Meier curves of every agent on one scenario: large, the legend outside the
    curves, the reference emphasised."""
    plt = _pyplot()
    colours = colours or agent_colours([s.agent for s in summaries], reference)
    fig, ax = plt.subplots(figsize=(10.0, 5.6))
    for s in summaries:
        c = s.survival
        emphasis = s.agent == reference
        ax.step(c.time, c.survival, where="post", label=s.agent, color=colours[s.agent],
                lw=2.6 if emphasis else 1.5, zorder=3 if emphasis else 2)  # fmt: skip
        ax.fill_between(c.time, c.low, c.high, step="post", alpha=0.12, color=colours[s.agent])
    ax.set_xlabel("time since episode start, s")
    ax.set_ylabel("share of episodes not yet captured")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(f"{scenario}: time to capture (Kaplan-Meier, failures censored)")
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
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


def ratio_figure(
    records: Sequence[EpisodeRecord],
    colours: dict[str, str] | None = None,
    reference: str | None = None,
) -> bytes:
    """Distribution of capture time / physical-limit time per agent, one panel per scenario, on
    one logarithmic axis shared by every panel (1.18x against 1.30x stays visible beside 100x)."""
    scenarios = list(dict.fromkeys(r.scenario for r in records))
    agents = list(dict.fromkeys(r.agent for r in records))
    colours = colours or agent_colours(agents, reference)
    fig, axes = _grid(len(scenarios))
    finite = [r.ratio for r in records if np.isfinite(r.ratio) and r.ratio > 0]
    low = min([*finite, 1.0]) * 0.9
    high = max([*finite, 2.0]) * 1.1
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
            boxes = ax.boxplot(data, showfliers=True, patch_artist=True, **_horizontal())
            for patch, name in zip(boxes["boxes"], names):
                patch.set_facecolor(colours[name])
                patch.set_alpha(0.55)
            ax.set_yticks(range(1, len(names) + 1), names)
            ax.invert_yaxis()
        else:
            ax.text(0.5, 0.5, "no capture", ha="center", va="center", transform=ax.transAxes)
        ax.set_xscale("log")
        ax.set_xlim(low, high)
        ax.axvline(1.0, color="k", lw=0.8, ls="--")
        ax.set_xlabel("capture time / physical limit (log)")
        ax.set_title(scenario)
        ax.grid(alpha=0.3, axis="x", which="both")
    fig.suptitle("Ratio to the physical limit (captured episodes; 1 = the bound; one log axis)")
    fig.tight_layout()
    return _png(fig)


def heatmap_figure(rate: np.ndarray, ratio: np.ndarray, agents: Sequence[str],
                   scenarios: Sequence[str]) -> bytes:  # fmt: skip
    """Agent x scenario: colour = capture rate, text = rate and median ratio to the limit."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(1.3 * len(scenarios) + 3.0, 0.55 * len(agents) + 1.6))
    image = ax.imshow(rate, cmap="viridis", vmin=0.0, vmax=1.0, aspect="auto")
    for i in range(len(agents)):
        for j in range(len(scenarios)):
            if np.isnan(rate[i, j]):
                continue
            text = f"{rate[i, j]:.0%}"
            if np.isfinite(ratio[i, j]):
                text += f"\n{ratio[i, j]:.2f}x"
            ax.text(j, i, text, ha="center", va="center", fontsize=8,
                    color="black" if rate[i, j] > 0.6 else "white")  # fmt: skip
    ax.set_xticks(range(len(scenarios)), scenarios, rotation=30, ha="right")
    ax.set_yticks(range(len(agents)), agents)
    fig.colorbar(image, ax=ax, label="capture rate", fraction=0.03)
    ax.set_title("Capture rate (colour) and median ratio to the physical limit, per scenario")
    return _png(fig)


def ranking_figure(rows: Sequence[Any], colours: dict[str, str]) -> bytes:
    """The ranking: mean capture rate over the ranked scenarios with its 95% bootstrap interval,
    best at the top, each agent labelled with its rank and its 95% rank interval; the agents of
    a tie group (rank intervals overlapping the agent ranked just above) share a shaded band
    named by its ranks, and "=" marks an agent tied with the one above it."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8.0, 0.45 * len(rows) + 1.4))
    shade = 0
    for k, row in enumerate(rows):
        line = row.row
        if line.tied and line.tie_first == line.rank:
            size = line.tie_last - line.tie_first + 1
            ax.axhspan(k - 0.45, k + size - 0.55, color=("0.86", "0.93")[shade % 2], zorder=0)
            ax.text(1.01, k + (size - 1) / 2, f"tied: ranks {line.tie_first}–{line.tie_last}",
                    transform=ax.get_yaxis_transform(), ha="left", va="center", fontsize=8,
                    color="0.3")  # fmt: skip
            shade += 1
        ax.errorbar(row.mean_capture_rate, k, xerr=[[row.mean_capture_rate - row.low],
                    [row.high - row.mean_capture_rate]], fmt="o", color=colours[row.agent],
                    capsize=3, zorder=2)  # fmt: skip
        if row.tied_with_previous:
            ax.annotate("=", (row.high, k - 0.5), xytext=(6, 0), textcoords="offset points",
                        va="center", fontsize=11, color="0.3")  # fmt: skip
    ax.set_yticks(range(len(rows)), [_rank_label(r.row) for r in rows])
    ax.set_ylim(len(rows) - 0.5, -0.5)
    ax.set_xlabel("mean capture rate over ranked scenarios (95% paired bootstrap over seeds)")
    ax.set_xlim(-0.02, 1.05)
    ax.grid(alpha=0.3, axis="x")
    ax.set_title(
        'Overall ranking: rank [95% rank interval]; shaded, "=": tied (rank intervals overlap)'
    )
    return _png(fig)


def _rank_label(row: Any) -> str:
    interval = "" if row.rank_low is None else f" [{row.rank_low}–{row.rank_high}]"
    return f"{row.rank}. {row.agent}{interval}"


def improvement_figure(matrix: np.ndarray, agents: Sequence[str]) -> bytes:
    """P(row > column), the probability of improvement (rliable's definition)."""
    plt = _pyplot()
    n = len(agents)
    fig, ax = plt.subplots(figsize=(0.7 * n + 3.0, 0.6 * n + 2.0))
    image = ax.imshow(matrix, cmap="RdBu", vmin=0.0, vmax=1.0)
    for i in range(n):
        for j in range(n):
            if i != j and np.isfinite(matrix[i, j]):
                ax.text(j, i, f"{matrix[i, j]:.2f}", ha="center", va="center", fontsize=7)
    ax.set_xticks(range(n), agents, rotation=40, ha="right")
    ax.set_yticks(range(n), agents)
    fig.colorbar(image, ax=ax, label="P(row beats column)", fraction=0.04)
    ax.set_title("Probability of improvement (per-episode score, averaged over scenarios)")
    return _png(fig)


def performance_profile_figure(
    profiles: dict[str, Any], colours: dict[str, str], reference: str | None = None
) -> bytes:
    """rliable's performance profiles (`capture_bench.rliable_stats.Profile` per agent):
    the share of an agent's episodes scoring above each threshold tau, with its 95% stratified
    bootstrap band; the reference emphasised, the legend outside the curves."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10.0, 5.6))
    rliable_stats.draw_profiles(ax, profiles, colours, reference)
    ax.set_title("Performance profile (rliable): every scenario's episodes, 95% bootstrap bands")
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
