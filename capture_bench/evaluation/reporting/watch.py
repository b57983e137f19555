"""Episodes to watch: which episodes the report shows on video, and its section.

For each scenario: the suite's reference (the paper's controller, ``incremental_ik``) and the
learned agent ranked highest in the overall ranking (a trained model), on one seed: the first
evaluated seed on which the reference captured, or the first seed if it captured on none. Without
a trained model in the run only the reference is shown; without the reference, the best-ranked
model on the first seed it captured. The videos themselves are made by
`capture_bench.evaluation.running.video`; this module only chooses and lays them out.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from capture_bench.evaluation.reporting.aggregate import RankingRow
from capture_bench.evaluation.running.rollout import EpisodeRecord

if TYPE_CHECKING:
    from capture_bench.evaluation.running.video import EpisodeVideo

TITLE = "Episodes to watch"
#: Said under the section's title, in both the Markdown and the HTML report.
INTRO = (
    "For each scenario, the reference (the paper's controller) and the best-ranked learned "
    "agent (trained model) of the overall ranking, on the same seed: the first evaluated seed on "
    "which the reference captured (the first seed if it captured on none). The same episodes as "
    "in the tables, rendered by pybullet: the target's trace in red, the end-effector's in blue; "
    "played at half speed, the last frame held."
)
STYLE = (
    ".videos{display:flex;flex-wrap:wrap;gap:1.5em}"
    ".videos figure{margin:0;width:320px}.videos figcaption{font-size:0.85em}"
)


@dataclass(frozen=True)
class Watch:
    """One scenario's episodes to watch: the scenario (its report name), the seed, the agents."""

    scenario: str
    seed: int
    agents: tuple[str, ...]


def watched_agents(
    ranking: Sequence[RankingRow], reference: str, learned: Collection[str]
) -> list[str]:
    """The reference (if it was evaluated) and the best-ranked agent of ``learned``, if any."""
    evaluated = [row.agent for row in ranking]
    best = next((row.agent for row in ranking if row.agent in learned), None)
    return [a for a in (reference if reference in evaluated else None, best) if a is not None]


def choose_episodes(
    records: Sequence[EpisodeRecord],
    ranking: Sequence[RankingRow],
    reference: str,
    learned: Collection[str],
) -> list[Watch]:
    """One `Watch` per scenario, in report order (none if no agent is watched).

    Args:
        records: every episode of the run (each agent's seeds in evaluation order).
        ranking: the overall ranking.
        reference: the suite's reference agent.
        learned: labels of the trained-model agents of the run.
    """
    agents = watched_agents(ranking, reference, learned)
    if not agents:
        return []
    watches = []
    for scenario in dict.fromkeys(r.scenario for r in records):
        own = [r for r in records if (r.agent, r.scenario) == (agents[0], scenario)]
        chosen = next((r for r in own if r.captured), own[0])
        watches.append(Watch(scenario, chosen.seed, tuple(agents)))
    return watches


def embedded_figure(
    data: bytes,
    mime: str,
    caption: str,
    size: tuple[int, int] | None = None,
    alt: str | None = None,
) -> str:
    """An image inlined as base64 in a ``<figure>`` with its caption (the page stays one file);
    ``size``: (width, height) attributes; ``alt``: what the image shows, for a reader who cannot
    see it (default the caption). The report's plots use it too."""
    encoded = base64.b64encode(data).decode("ascii")
    dims = "" if size is None else f'width="{size[0]}" height="{size[1]}" '
    described = html.escape(caption if alt is None else alt, quote=True)
    return (
        f'<figure><img alt="{described}" {dims}src="data:{mime};base64,{encoded}">'
        f"<figcaption>{html.escape(caption)}</figcaption></figure>"
    )


def _gif(video: EpisodeVideo) -> str:
    caption = video.caption()
    alt = f"Animation of one episode, rendered by pybullet: {caption}"
    return embedded_figure(video.gif, "image/gif", caption, (320, 240), alt)


def _by_scenario(videos: Sequence[EpisodeVideo]) -> dict[str, list[EpisodeVideo]]:
    grouped: dict[str, list[EpisodeVideo]] = {}
    for video in videos:
        grouped.setdefault(video.record.scenario, []).append(video)
    return grouped


def html_section(videos: Sequence[EpisodeVideo]) -> str:
    """The section of ``leaderboard.html``: GIFs inlined as base64, one row per scenario."""
    if not videos:
        return ""
    parts = [f"<h2>{TITLE}</h2>", f"<p>{html.escape(INTRO)}</p>"]
    for scenario, group in _by_scenario(videos).items():
        parts.append(f"<h3>{html.escape(scenario)}</h3>")
        parts.append('<div class="videos">' + "".join(_gif(v) for v in group) + "</div>")
    return "\n".join(parts)


def markdown_lines(videos: Sequence[EpisodeVideo]) -> list[str]:
    """The section of ``leaderboard.md``: the GIF files written next to it."""
    if not videos:
        return []
    lines = [f"## {TITLE}", "", INTRO, ""]
    for scenario, group in _by_scenario(videos).items():
        lines += [f"### {scenario}", ""]
        lines += [f"![{v.caption()}]({v.file_name})" for v in group]
        lines.append("")
    return lines
