"""Report figures as PNG bytes (matplotlib, Agg backend, imported lazily).

* survival curves per scenario: Kaplan-Meier share of episodes not yet captured vs time, s, with
  the 95% band; failures are censored at the time their episode ended;
* failures by reason: per scenario, each agent's episodes split into captured and each reason;
* ratio to the physical limit: per scenario, the distribution of capture time / bound per agent;
* one episode: distance, estimate error and actions vs time (``--episode-plots``);
* the summary (`capture_bench.evaluation.reporting.summary`): the agent x scenario heatmap, the
  ranking with intervals, the probability-of-improvement matrix of the top agents;
* rliable's performance profiles (`capture_bench.evaluation.reporting.rliable_report`).

Sized for what they hold, to be read at their natural size: every figure's height grows with its
number of agent rows (`ROW_INCHES` each, so no two tick labels overlap), its width stays within
`MAX_WIDTH_INCHES` (the report page shows it unscaled at a desktop width) and its smallest text
is `STYLE`'s 8 pt, 10 px at `DPI`. Agents are in the order given (the report's: the ranking's).

Every agent has one colour in every figure (`agent_colours`: 30 colours distinct to the eye,
Okabe & Ito's colour-blind-safe palette first, in the agents' order) and, in the line plots, one
line style (`agent_line_styles`: solid for the first ten, then dashed, dash-dotted, dotted); the
reference agent (the paper's controller) is drawn black and thicker.
"""

from __future__ import annotations

import functools
import io
import math
import textwrap
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from capture_bench import rliable_stats
from capture_bench.evaluation.reporting.aggregate import Summary
from capture_bench.evaluation.running.rollout import EpisodeRecord, EpisodeTrace

DPI = 90
#: matplotlib's font sizes, points (1.25 px each at `DPI`), for every report figure.
STYLE = {
    "font.size": 10,
    "axes.titlesize": 11,
    "axes.labelsize": 10,
    "xtick.labelsize": 9,
    "ytick.labelsize": 9,
    "legend.fontsize": 9,
    "figure.titlesize": 12,
}
#: The height of one agent row in the bar, box, heatmap and ranking figures, inches.
ROW_INCHES = 0.3
#: The widest a figure is drawn, inches (1,125 px at `DPI`: under the report page's column).
MAX_WIDTH_INCHES = 12.5
OUTCOME_COLOURS = {
    "captured": "tab:green",
    "timeout": "tab:gray",
    "collision": "tab:red",
    "target_lost": "tab:orange",
    "unreachable": "tab:purple",
}

#: Okabe & Ito's colour-blind-safe palette (without black, kept for the reference), then 23 more
#: chosen one by one as far as possible (CIELAB distance) from those before them, from black and
#: from white: any two of the 30 are at least 26 CIELAB units apart.
PALETTE = ("#E69F00", "#56B4E9", "#009E73", "#0072B2", "#D55E00", "#CC79A7", "#F0E442",
           "#544E03", "#7B68EE", "#69D84F", "#BE013C", "#696969", "#CFAF7B", "#800080",
           "#FE46A5", "#006400", "#7F2B0A", "#889717", "#FA8072", "#EE82EE", "#483D8B",
           "#00CED1", "#960056", "#12E193", "#CEAEFA", "#9A6200", "#017A79", "#1E90FF",
           "#B1D27B", "#2B5D34")  # fmt: skip
REFERENCE_COLOUR = "#000000"
#: Line styles, each for ten agents in turn (`agent_line_styles`).
LINE_STYLES = ("-", "--", "-.", ":")
#: How many agents (the best-ranked) the probability-of-improvement matrix shows.
IMPROVEMENT_TOP = 10
#: The ranking figure draws its agents in two panels, each on its own x axis, where that makes
#: both at least this many times as wide on the page as one axis for all (`ranking_layout`).
SPLIT_ZOOM = 3.0
#: The narrowest x range of a ranking panel (capture rate).
MIN_PANEL_SPAN = 0.1
#: The heatmap's colour classes of the capture rate: the lower edges; a rate of exactly 1 is a
#: class of its own, so 99% and 100% differ, as do 86%, 95% and 100%.
RATE_EDGES = (0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99)


def _others(agents: Sequence[str], reference: str | None) -> list[str]:
    return [a for a in agents if a != reference]


def agent_colours(agents: Sequence[str], reference: str | None = None) -> dict[str, str]:
    """One colour per agent, the same in every figure of a report: the reference black, the
    others `PALETTE` in order (all distinct up to 30 others; cycling past them, where
    `agent_line_styles` still tells the agents apart)."""
    colours = {a: PALETTE[i % len(PALETTE)] for i, a in enumerate(_others(agents, reference))}
    if reference is not None and reference in agents:
        colours[reference] = REFERENCE_COLOUR
    return colours


def agent_line_styles(agents: Sequence[str], reference: str | None = None) -> dict[str, str]:
    """One line style per agent for the curves: the reference and the first ten others solid,
    the next ten dashed, then dash-dotted, then dotted (colour and style together differ for
    any two of up to 40 agents)."""
    styles = {a: LINE_STYLES[(i // 10) % len(LINE_STYLES)]
              for i, a in enumerate(_others(agents, reference))}  # fmt: skip
    if reference is not None and reference in agents:
        styles[reference] = "-"
    return styles


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _styled(draw: Callable[..., bytes]) -> Callable[..., bytes]:
    """``draw`` with matplotlib's font sizes set to `STYLE` while it draws and saves."""

    @functools.wraps(draw)
    def wrapper(*args: Any, **kwargs: Any) -> bytes:
        with _pyplot().rc_context(STYLE):
            return draw(*args, **kwargs)

    return wrapper


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


def _text_inches(labels: Sequence[str], points: float = 9.0) -> float:
    """About how wide the longest of ``labels`` is at ``points``, inches."""
    return 0.56 * points / 72 * max((len(s) for s in labels), default=0)


def _rows_inches(rows: int) -> float:
    return ROW_INCHES * max(rows, 1)


def _panels(
    n: int, rows: int, panel_width: float, labels: float, columns: int, extra: float = 1.1
) -> tuple[Any, list[Any]]:
    """``n`` panels of ``rows`` agent rows each sharing one y axis, up to ``columns`` to a line
    (fewer where they would pass `MAX_WIDTH_INCHES`), the agents' names (``labels`` inches wide)
    on the first panel of each line only."""
    plt = _pyplot()
    fit = max(1, min(n, columns, int((MAX_WIDTH_INCHES - labels - 0.3) // panel_width)))
    lines = math.ceil(n / fit)
    cols = math.ceil(n / lines)  # the lines as even as they go
    height = lines * (_rows_inches(rows) + extra) + 0.9
    fig, axes = plt.subplots(lines, cols, figsize=(labels + panel_width * cols + 0.3, height),
                             sharey=True, squeeze=False, layout="constrained")  # fmt: skip
    fig.get_layout_engine().set(w_pad=0.06, wspace=0.04)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


def _agent_axis(ax: Any, agents: Sequence[str]) -> None:
    ax.set_yticks(range(len(agents)), agents)
    ax.set_ylim(len(agents) - 0.5, -0.5)


@_styled
def survival_figure(
    scenario: str,
    summaries: Sequence[Summary],
    colours: dict[str, str] | None = None,
    reference: str | None = None,
    styles: dict[str, str] | None = None,
) -> bytes:
    """Kaplan-Meier curves of every agent on one scenario, in the order of ``summaries``: the
    legend outside the curves (one entry per agent, so the figure grows with them), the reference
    emphasised."""
    plt = _pyplot()
    agents = [s.agent for s in summaries]
    colours = colours or agent_colours(agents, reference)
    styles = styles or agent_line_styles(agents, reference)
    fig, ax = plt.subplots(figsize=(8.6, max(4.8, 0.23 * len(agents) + 0.9)))
    for s in summaries:
        c = s.survival
        emphasis = s.agent == reference
        ax.step(c.time, c.survival, where="post", label=s.agent, color=colours[s.agent],
                ls=styles[s.agent], lw=2.6 if emphasis else 1.5,
                zorder=3 if emphasis else 2)  # fmt: skip
        ax.fill_between(c.time, c.low, c.high, step="post", alpha=0.1, color=colours[s.agent])
    ax.set_xlabel("time since episode start, s")
    ax.set_ylabel("share of episodes not yet captured")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(f"{scenario}: time to capture (Kaplan-Meier, failures censored)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.grid(alpha=0.3)
    return _png(fig)


@_styled
def failures_figure(
    summaries: Sequence[Summary], reasons: Sequence[str], agents: Sequence[str] | None = None
) -> bytes:
    """Stacked shares of outcomes (captured, then each failure reason): one narrow panel per
    scenario, side by side and sharing one row per agent (in ``agents``' order, default as they
    first appear), the legend on top."""
    scenarios = list(dict.fromkeys(s.scenario for s in summaries))
    agents = list(dict.fromkeys(s.agent for s in summaries)) if agents is None else list(agents)
    cells = {(s.agent, s.scenario): s for s in summaries}
    width = max(1.1, _text_inches(scenarios, 10) + 0.25)
    fig, axes = _panels(len(scenarios), len(agents), width, _text_inches(agents), 9, 0.9)
    rows = np.arange(len(agents))
    for ax, scenario in zip(axes, scenarios):
        present = [cells.get((a, scenario)) for a in agents]
        left = np.zeros(len(agents))
        for label in ["captured", *reasons]:
            share = np.array([
                0.0 if s is None or not s.episodes
                else (s.captured if label == "captured" else s.failures.get(label, 0)) / s.episodes
                for s in present
            ])  # fmt: skip
            ax.barh(rows, share, left=left, height=0.8, label=label.replace("_", " "),
                    color=OUTCOME_COLOURS.get(label))  # fmt: skip
            left += share
        _agent_axis(ax, agents)
        ax.set_xlim(0, 1)
        ax.set_xticks([0, 0.5, 1], ["0", "0.5", "1"])
        ax.set_xlabel("share")
        ax.set_title(scenario, fontsize=10)
    fig.suptitle("Outcomes: the share of episodes captured, or failed for each reason")
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside lower center", ncol=len(names), frameon=False)
    return _png(fig)


@_styled
def ratio_figure(
    records: Sequence[EpisodeRecord],
    colours: dict[str, str] | None = None,
    reference: str | None = None,
    agents: Sequence[str] | None = None,
) -> bytes:
    """Distribution of capture time / physical-limit time per agent (one row each, in
    ``agents``' order, default as they first appear), one panel per scenario, on one logarithmic
    axis shared by every panel (1.18x against 1.30x stays visible beside 100x)."""
    from matplotlib import ticker

    scenarios = list(dict.fromkeys(r.scenario for r in records))
    if agents is None:
        agents = list(dict.fromkeys(r.agent for r in records))
    agents = list(agents)
    colours = colours or agent_colours(agents, reference)
    fig, axes = _panels(len(scenarios), len(agents), 2.0, _text_inches(agents), 5)
    finite = [r.ratio for r in records if np.isfinite(r.ratio) and r.ratio > 0]
    low = min([*finite, 1.0]) * 0.9
    high = max([*finite, 2.0]) * 1.1
    for ax, scenario in zip(axes, scenarios):
        data, rows = [], []
        for k, agent in enumerate(agents):
            ratios = [r.ratio for r in records if r.scenario == scenario and r.agent == agent
                      and np.isfinite(r.ratio) and r.ratio > 0]  # fmt: skip
            if ratios:
                data.append(ratios)
                rows.append(k)
            else:
                ax.text(1.08, k, "no capture", va="center", fontsize=8, color="0.45")
        if data:
            boxes = ax.boxplot(data, positions=rows, widths=0.7, showfliers=True,
                               patch_artist=True, flierprops={"markersize": 3},
                               medianprops={"color": "black"},
                               **_horizontal())  # fmt: skip
            for patch, k in zip(boxes["boxes"], rows):
                patch.set_facecolor(colours[agents[k]])
                patch.set_alpha(0.6)
        _agent_axis(ax, agents)
        ax.set_xscale("log")
        ax.set_xlim(low, high)
        ticks = [t for t in _RATIO_TICKS if low <= t <= high]
        ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.axvline(1.0, color="k", lw=0.8, ls="--")
        ax.set_xlabel("capture time / limit")
        ax.set_title(scenario, fontsize=10)
        ax.grid(alpha=0.3, axis="x", which="both")
    fig.suptitle("Ratio of capture time to the physical limit (captured episodes; dashed: 1, "
                 "the limit; one log axis)")  # fmt: skip
    return _png(fig)


#: The ratio figure's x ticks (those in its range): 1, 2, 5 and their powers of ten.
_RATIO_TICKS = [m * 10.0**e for e in range(-1, 5) for m in (1, 2, 5)]


def rate_classes() -> list[str]:
    """The heatmap's colour classes of the capture rate, lowest first (`RATE_EDGES`)."""
    edges = [*RATE_EDGES, 1.0]
    names = [f"{edges[k]:.0%}–{edges[k + 1]:.0%}" for k in range(len(RATE_EDGES))]
    names[0] = f"<{edges[1]:.0%}"
    return [*names[:-1], f"{RATE_EDGES[-1]:.0%}–<100%", "100%"]


def rate_class(rate: float) -> float:
    """The index of ``rate``'s class in `rate_classes` (NaN for NaN)."""
    if math.isnan(rate):
        return math.nan
    if rate >= 1.0:
        return float(len(RATE_EDGES))
    return float(np.searchsorted(RATE_EDGES, rate, side="right") - 1)


def _percent(rate: float) -> str:
    """``86%``; one decimal where whole percent would round a rate under 1 up to ``100%``."""
    text = f"{rate:.0%}"
    return f"{rate:.1%}" if rate < 1.0 and text == "100%" else text


def _dark(rgba: Sequence[float]) -> bool:
    return 0.2126 * rgba[0] + 0.7152 * rgba[1] + 0.0722 * rgba[2] < 0.45


@_styled
def heatmap_figure(rate: np.ndarray, ratio: np.ndarray, agents: Sequence[str],
                   scenarios: Sequence[str]) -> bytes:  # fmt: skip
    """Agent x scenario: colour = capture rate in the classes of `rate_classes` (spending the
    colours near the top, where agents differ by a few episodes), text = rate and median ratio
    to the limit, at 10 pt."""
    import matplotlib.colors as mcolors

    plt = _pyplot()
    classes = rate_classes()
    cmap = plt.get_cmap("viridis").resampled(len(classes))
    norm = mcolors.BoundaryNorm(np.arange(len(classes) + 1) - 0.5, len(classes))
    index = np.vectorize(rate_class)(rate) if rate.size else rate
    width = 0.9 * len(scenarios) + _text_inches(agents) + 2.0
    fig, ax = plt.subplots(figsize=(width, _rows_inches(len(agents)) * 1.45 + 1.4),
                           layout="constrained")  # fmt: skip
    image = ax.imshow(np.ma.masked_invalid(index), cmap=cmap, norm=norm, aspect="auto")
    for i in range(len(agents)):
        for j in range(len(scenarios)):
            if np.isnan(rate[i, j]):
                continue
            text = _percent(rate[i, j])
            if np.isfinite(ratio[i, j]):
                text += f"\n{ratio[i, j]:.2f}x"
            ax.text(j, i, text, ha="center", va="center", fontsize=10, linespacing=1.1,
                    color="white" if _dark(cmap(norm(index[i, j]))) else "black")  # fmt: skip
    ax.set_xticks(range(len(scenarios)), scenarios, rotation=30, ha="right", fontsize=10)
    ax.set_yticks(range(len(agents)), agents, fontsize=10)
    bar = fig.colorbar(image, ax=ax, label="capture rate (classes)", fraction=0.04, aspect=30)
    bar.set_ticks(range(len(classes)), labels=classes)
    ax.set_title("Capture rate (colour) and median ratio to the physical limit, per scenario")
    return _png(fig)


def ranking_layout(rows: Sequence[Any]) -> tuple[list[list[Any]], list[Any]]:
    """``(panels, not drawn)`` of the ranking figure, from `ranking_intervals`' rows in rank
    order. The agents at capture rate 0 with an interval of [0, 0] (no capture on any ranked
    scenario: nothing to compare) are not drawn. The others go in one panel, or in two, cut
    where the rate falls furthest between consecutive agents, when the two panels' x ranges
    (`panel_limits`) together are under 1 / `SPLIT_ZOOM` of one axis for all: then each panel
    resolves its agents (the top ones, a few episodes apart, and the weak ones) that many times
    better."""
    floor = [r for r in rows if not (np.isfinite(r.high) and r.high > 0)]
    drawn = [r for r in rows if np.isfinite(r.high) and r.high > 0]
    if len(drawn) < 2:
        return ([drawn] if drawn else []), floor
    values = [r.mean_capture_rate for r in drawn]
    _, cut = max((values[k] - values[k + 1], k) for k in range(len(values) - 1))
    parts = [drawn[: cut + 1], drawn[cut + 1 :]]
    spans = [high - low for low, high in map(panel_limits, [drawn, *parts])]
    if SPLIT_ZOOM * (spans[1] + spans[2]) <= spans[0]:
        return parts, floor
    return [drawn], floor


def panel_limits(rows: Sequence[Any]) -> tuple[float, float]:
    """The x range of a ranking panel: its agents' intervals, at least `MIN_PANEL_SPAN` wide
    (inside [0, 1]), with a margin."""
    low = min(min(r.low, r.mean_capture_rate) for r in rows)
    high = max(max(r.high, r.mean_capture_rate) for r in rows)
    if high - low < MIN_PANEL_SPAN:
        middle = (low + high) / 2
        low, high = middle - MIN_PANEL_SPAN / 2, middle + MIN_PANEL_SPAN / 2
        if high > 1.0:
            low, high = low - (high - 1.0), 1.0
        if low < 0.0:
            low, high = 0.0, high - low
    margin = 0.04 * (high - low)
    return low - margin, high + margin


def rank_label(row: Any) -> str:
    """``3. dls [2–3]``: rank, agent and 95% rank interval."""
    interval = "" if row.rank_low is None else f" [{row.rank_low}–{row.rank_high}]"
    return f"{row.rank}. {row.agent}{interval}"


def not_drawn_note(floor: Sequence[Any]) -> str:
    """The ranking figure's note on the agents it does not draw (`ranking_layout`)."""
    if not floor:
        return ""
    return ("Not drawn: capture rate 0 on every ranked scenario, interval [0, 0]: "
            + ", ".join(rank_label(r.row) for r in floor) + ".")  # fmt: skip


@_styled
def ranking_figure(rows: Sequence[Any], colours: dict[str, str]) -> bytes:
    """The ranking: mean capture rate over the ranked scenarios with its 95% bootstrap interval,
    best at the top, each agent labelled with its rank and its 95% rank interval; the agents of
    a tie group (rank intervals overlapping the agent ranked just above) share a shaded band
    named by its ranks, and "=" marks an agent tied with the one above it.

    Drawn for the agents it holds (`ranking_layout`): agents at 0 with nothing to compare are
    named in a note under the panels instead, and where the rates fall far between two agents
    the agents above and below are two panels, each with its own x axis (`panel_limits`), so
    the top agents, a few episodes apart, are resolved and so are the weak ones."""
    plt = _pyplot()
    panels, floor = ranking_layout(rows)
    note = textwrap.fill(not_drawn_note(floor), 110)
    labels = _text_inches([rank_label(r.row) for r in rows], 10)
    counts = [len(p) for p in panels] or [1]
    height = sum(_rows_inches(n) + 0.8 for n in counts) + 0.6 + 0.2 * (note.count("\n") + 1)
    fig, axes = plt.subplots(len(counts), 1, figsize=(labels + 7.5, height), squeeze=False,
                             layout="constrained",
                             gridspec_kw={"height_ratios": [n + 2.7 for n in counts]})  # fmt: skip
    shades = {}
    for ax, panel in zip(axes[:, 0], panels):
        _ranking_panel(ax, panel, colours, shades)
    if not panels:
        axes[0, 0].text(0.5, 0.5, "no agent to draw", ha="center", va="center")
        axes[0, 0].set_axis_off()
    if note:
        fig.supxlabel(note, fontsize=9, color="0.25", ha="center")
    fig.suptitle('Overall ranking: rank [95% rank interval]; shaded, "=": tied '
                 "(rank intervals overlap)")  # fmt: skip
    return _png(fig)


def _ranking_panel(ax: Any, panel: Sequence[Any], colours: dict[str, str], shades: dict) -> None:
    start = 0
    while start < len(panel):
        line = panel[start].row
        end = start
        if line.tied:
            while end + 1 < len(panel) and panel[end + 1].row.tie_first == line.tie_first:
                end += 1
            shade = shades.setdefault(line.tie_first, len(shades))
            ax.axhspan(start - 0.45, end + 0.45, color=("0.86", "0.93")[shade % 2], zorder=0)
            ax.text(1.01, (start + end) / 2, f"tied: ranks {line.tie_first}–{line.tie_last}",
                    transform=ax.get_yaxis_transform(), ha="left", va="center", fontsize=9,
                    color="0.3")  # fmt: skip
        start = end + 1
    for k, row in enumerate(panel):
        ax.errorbar(row.mean_capture_rate, k, xerr=[[row.mean_capture_rate - row.low],
                    [row.high - row.mean_capture_rate]], fmt="o", color=colours[row.agent],
                    capsize=3, zorder=2)  # fmt: skip
        if row.tied_with_previous and k > 0:
            ax.annotate("=", (row.high, k - 0.5), xytext=(6, 0), textcoords="offset points",
                        va="center", fontsize=11, color="0.3")  # fmt: skip
    ax.set_yticks(range(len(panel)), [rank_label(r.row) for r in panel], fontsize=10)
    ax.set_ylim(len(panel) - 0.5, -0.5)
    ax.set_xlim(*panel_limits(panel))
    ax.set_xlabel("mean capture rate over ranked scenarios (95% paired bootstrap over seeds)")
    ax.grid(alpha=0.3, axis="x")


def improvement_agents(agents: Sequence[str]) -> list[str]:
    """The agents of the probability-of-improvement matrix: the first `IMPROVEMENT_TOP` of
    ``agents`` (ranking order: the best-ranked)."""
    return list(agents[:IMPROVEMENT_TOP])


@_styled
def improvement_figure(matrix: np.ndarray, agents: Sequence[str]) -> bytes:
    """P(row > column), the probability of improvement (rliable's definition), of ``agents``
    (`improvement_agents`: a large matrix's numbers would be unreadable), values at 10 pt; the
    rows named ``1. agent``, the columns by the same numbers."""
    plt = _pyplot()
    n = len(agents)
    names = [f"{k + 1}. {agent}" for k, agent in enumerate(agents)]
    labels = _text_inches(names, 10)
    fig, ax = plt.subplots(figsize=(0.7 * n + labels + 2.0, 0.55 * n + 1.6),
                           layout="constrained")  # fmt: skip
    image = ax.imshow(matrix, cmap="RdBu", vmin=0.0, vmax=1.0, aspect="auto")
    for i in range(n):
        for j in range(n):
            if i != j and np.isfinite(matrix[i, j]):
                extreme = abs(matrix[i, j] - 0.5) > 0.32
                ax.text(j, i, f"{matrix[i, j]:.2f}", ha="center", va="center", fontsize=10,
                        color="white" if extreme else "black")  # fmt: skip
    ax.set_xticks(range(n), [str(k + 1) for k in range(n)], fontsize=10)
    ax.set_yticks(range(n), names, fontsize=10)
    ax.set_xlabel("column: the agent of the row with that number")
    fig.colorbar(image, ax=ax, label="P(row beats column)", fraction=0.04)
    ax.set_title(f"Probability of improvement, top {n} by rank (per-episode score, averaged "
                 "over scenarios)")  # fmt: skip
    return _png(fig)


@_styled
def performance_profile_figure(
    profiles: dict[str, Any],
    colours: dict[str, str],
    reference: str | None = None,
    styles: dict[str, str] | None = None,
) -> bytes:
    """rliable's performance profiles (`capture_bench.rliable_stats.Profile` per agent):
    the share of an agent's episodes scoring above each threshold tau, with its 95% stratified
    bootstrap band; the reference emphasised, the legend outside the curves (one entry per
    agent, so the figure grows with them)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8.6, max(4.8, 0.23 * len(profiles) + 0.9)))
    rliable_stats.draw_profiles(ax, profiles, colours, reference, styles=styles)
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
