"""Rendered against analytic vision: an agent on a scenario and on its rendered twin, seed by seed.

A scenario ``X_rendered`` is the *rendered twin* of ``X`` when both are shipped, ``X`` has the
analytic camera (the markers' centres projected by eq. 2 plus pixel noise), ``X_rendered`` the
rendered one (pybullet renders the image and the markers are found in its pixels, so the arm can
hide them), and both have the same published evaluation seeds: seed s is then the same target in
both, and the two episodes of an agent on seed s differ only in the vision.

Each agent evaluated on both scenarios of a pair is compared on the seeds it was evaluated on in
both (`compare`: side A the analytic scenario, side B the
rendered one, so a positive paired difference in ratio is slower with rendered vision).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any

from capture_bench.evaluation.reporting import paired
from capture_bench.evaluation.reporting.paired import Paired, PairedSection
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.task.scenarios import Scenario, load_scenario
from capture_bench.validation import ConfigError

#: ``X`` + this suffix names the rendered twin of scenario ``X``.
RENDERED_SUFFIX = "_rendered"
TITLE = "Rendered vs analytic vision"
#: Said under the section's title, in both the Markdown and the HTML report.
TEXT = (
    "Each agent on a scenario with the analytic camera (markers projected exactly, plus pixel "
    "noise) and on its rendered twin (markers found in pybullet's rendered image, where the arm "
    "can hide them), on the same seeds, hence the same targets: Δ capture rate is "
    "rendered minus analytic over the seeds evaluated in both (a seed counts -1, 0 or +1; 95% "
    "paired percentile bootstrap over seeds), next to the seeds captured by one camera only, and "
    "paired Δ ratio is the median over seeds captured by both of the rendered minus the analytic "
    "ratio of capture time to the physical limit (positive: slower with rendered vision)."
)
#: ``results.json``'s ``vision`` entries name the agent and the two scenarios by these keys.
COLUMNS = ("agent", "analytic", "rendered")
HEADER = paired.header("analytic", "rendered", "agent")


def rendered_twins(
    scenarios: Iterable[str], load: Callable[[str], Scenario] = load_scenario
) -> list[tuple[str, str]]:
    """The (``X``, ``X_rendered``) pairs among ``scenarios`` (names, in their order) that are
    twins (module docstring); a name ``load`` cannot load (a scenario given by a path whose stem
    is no shipped scenario) pairs with nothing."""
    names = list(dict.fromkeys(scenarios))
    pairs = []
    for name in names:
        twin = name + RENDERED_SUFFIX
        if twin not in names:
            continue
        try:
            analytic, rendered = load(name), load(twin)
        except ConfigError:
            continue
        modes = (analytic.camera.mode, rendered.camera.mode)
        if modes == ("analytic", "rendered") and list(analytic.evaluation_seeds) == list(
            rendered.evaluation_seeds
        ):
            pairs.append((name, twin))
    return pairs


def vision_comparisons(
    records: Sequence[EpisodeRecord], pairs: Sequence[tuple[str, str]] | None = None
) -> list[Paired]:
    """Every agent x twin pair with a seed evaluated in both scenarios (subject: the agent; side
    A: ``X``, side B: ``X_rendered``), pair by pair in the order the scenarios first appear in
    ``records``, agents likewise.

    Args:
        records: the report's episodes.
        pairs: the (analytic, rendered) scenario pairs; None for `rendered_twins` of the
            scenarios in ``records``.
    """
    if pairs is None:
        pairs = rendered_twins(r.scenario for r in records)
    cells = paired.by_seed(records)
    agents = list(dict.fromkeys(r.agent for r in records))
    out = []
    for x, x_rendered in pairs:
        for agent in agents:
            analytic = cells.get((agent, x), {})
            rendered = cells.get((agent, x_rendered), {})
            if set(analytic) & set(rendered):
                out.append(paired.compare(agent, analytic, rendered, (x, x_rendered)))
    return out


def left_out_text(comparisons: Sequence[Paired]) -> str:
    """One sentence naming the seeds evaluated in one scenario of a pair only ("" if none)."""
    return paired.left_out_text(comparisons, "in one scenario of the pair only")


def comparison_row(c: Paired) -> dict[str, Any]:
    """One entry of ``results.json``'s ``vision`` list."""
    return paired.comparison_row(c, COLUMNS)


def section(records: Sequence[EpisodeRecord]) -> PairedSection | None:
    """The report's section, one table per twin pair; None where the report holds no pair."""
    comparisons = vision_comparisons(records)
    if not comparisons:
        return None
    tables: dict[str, list[Paired]] = {}
    for c in comparisons:
        tables.setdefault(f"{c.a} vs {c.b}", []).append(c)
    return PairedSection(
        TITLE, TEXT, "vision", COLUMNS, HEADER, list(tables.items()), left_out_text(comparisons)
    )
