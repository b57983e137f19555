"""Rendered against analytic vision: an agent on a scenario and on its rendered twin, seed by seed.

A scenario ``X_rendered`` is the *rendered twin* of ``X`` when both are shipped, ``X`` has the
analytic camera (the markers' centres projected by eq. 2 plus pixel noise), ``X_rendered`` the
rendered one (pybullet renders the image and the markers are found in its pixels, so the arm can
hide them), and both have the same published evaluation seeds: seed s is then the same target in
both, and the two episodes of an agent on seed s differ only in the vision.

For each agent evaluated on both scenarios of a pair, on the seeds it was evaluated on in both
(:class:`VisionComparison`; a seed evaluated in one scenario only is left out and counted):

* capture rate with each camera, Wilson 95% interval;
* their difference, rendered minus analytic: the mean over seeds of (captured with rendered
  vision) - (captured with analytic vision), each term -1, 0 or +1, with a 95% percentile
  bootstrap interval resampling the seeds (paired); the seeds captured by one camera only
  (McNemar's discordant pairs) are counted beside it;
* median ratio of capture time to the physical limit with each camera, over that camera's captured
  episodes, bootstrap interval;
* paired ratio difference: the median over seeds captured with both cameras of (rendered ratio -
  analytic ratio), bootstrap interval over those seeds; positive is slower with rendered vision.

The intervals are :func:`~capture_bench.evaluation.metrics.bootstrap_estimate`'s and
:func:`~capture_bench.evaluation.metrics.wilson_interval`'s, as in the rest of the report.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from capture_bench.evaluation.metrics import Estimate, bootstrap_estimate, wilson_interval
from capture_bench.evaluation.rollout import EpisodeRecord
from capture_bench.task.scenarios import Scenario, load_scenario
from capture_bench.validation import ConfigError

#: ``X`` + this suffix names the rendered twin of scenario ``X``.
RENDERED_SUFFIX = "_rendered"
TITLE = "Rendered vs analytic vision"
#: Said under the section's title, in both the Markdown and the HTML report.
TEXT = (
    "Each agent on a scenario with the analytic camera (markers projected exactly, plus pixel "
    "noise) and on its rendered twin (markers found in pybullet's rendered image, where the arm "
    "can hide them), on the same published seeds, hence the same targets: Δ capture rate is "
    "rendered minus analytic over the seeds evaluated in both (a seed counts -1, 0 or +1; 95% "
    "paired percentile bootstrap over seeds), next to the seeds captured by one camera only, and "
    "paired Δ ratio is the median over seeds captured by both of the rendered minus the analytic "
    "ratio of capture time to the physical limit (positive: slower with rendered vision)."
)


@dataclass(frozen=True)
class VisionComparison:
    """One agent on an analytic scenario and on its rendered twin, paired by seed.

    Attributes:
        agent: the agent.
        analytic, rendered: the two scenarios' names (``X``, ``X_rendered``).
        seeds: number of seeds evaluated in both, the pairs every figure is computed on.
        captured_analytic, captured_rendered: captures among those seeds with each camera.
        capture_rate_analytic, capture_rate_rendered: share captured, Wilson 95% interval.
        capture_rate_difference: rendered minus analytic share, paired bootstrap interval.
        only_analytic, only_rendered, both_captured: seeds captured by the analytic camera only,
            by the rendered camera only, by both.
        ratio_median_analytic, ratio_median_rendered: median capture time / physical limit over
            the captured episodes of the paired seeds, bootstrap interval.
        ratio_difference: median over the seeds captured by both of (rendered ratio - analytic
            ratio), bootstrap interval; positive is slower with rendered vision.
        unpaired_analytic, unpaired_rendered: seeds evaluated in only that scenario of the pair,
            sorted; left out of every figure.
    """

    agent: str
    analytic: str
    rendered: str
    seeds: int
    captured_analytic: int
    captured_rendered: int
    capture_rate_analytic: Estimate
    capture_rate_rendered: Estimate
    capture_rate_difference: Estimate
    only_analytic: int
    only_rendered: int
    both_captured: int
    ratio_median_analytic: Estimate
    ratio_median_rendered: Estimate
    ratio_difference: Estimate
    unpaired_analytic: tuple[int, ...] = ()
    unpaired_rendered: tuple[int, ...] = ()


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


def _by_seed(records: Iterable[EpisodeRecord]) -> dict[tuple[str, str], dict[int, EpisodeRecord]]:
    cells: dict[tuple[str, str], dict[int, EpisodeRecord]] = {}
    for r in records:
        cells.setdefault((r.agent, r.scenario), {})[r.seed] = r
    return cells


def compare(
    agent: str,
    analytic: dict[int, EpisodeRecord],
    rendered: dict[int, EpisodeRecord],
    names: tuple[str, str],
) -> VisionComparison:
    """One agent's comparison from its episodes by seed in ``X`` and in ``X_rendered``
    (``names``); at least one seed must be in both."""
    seeds = sorted(set(analytic) & set(rendered))
    if not seeds:
        raise ValueError(f"{agent}: no seed evaluated in both {names[0]} and {names[1]}")
    a = [analytic[s] for s in seeds]
    r = [rendered[s] for s in seeds]
    got_a = np.array([e.captured for e in a], dtype=float)
    got_r = np.array([e.captured for e in r], dtype=float)
    both = (got_a == 1) & (got_r == 1)
    ratio_a = np.array([e.ratio if e.captured else math.nan for e in a])
    ratio_r = np.array([e.ratio if e.captured else math.nan for e in r])
    return VisionComparison(
        agent=agent,
        analytic=names[0],
        rendered=names[1],
        seeds=len(seeds),
        captured_analytic=int(got_a.sum()),
        captured_rendered=int(got_r.sum()),
        capture_rate_analytic=wilson_interval(int(got_a.sum()), len(seeds)),
        capture_rate_rendered=wilson_interval(int(got_r.sum()), len(seeds)),
        capture_rate_difference=bootstrap_estimate(got_r - got_a, "mean"),
        only_analytic=int(((got_a == 1) & (got_r == 0)).sum()),
        only_rendered=int(((got_a == 0) & (got_r == 1)).sum()),
        both_captured=int(both.sum()),
        ratio_median_analytic=bootstrap_estimate(ratio_a, "median"),
        ratio_median_rendered=bootstrap_estimate(ratio_r, "median"),
        # a ratio that is not finite (no finite bound) drops out, as in every ratio figure
        ratio_difference=bootstrap_estimate(ratio_r[both] - ratio_a[both], "median"),
        unpaired_analytic=tuple(sorted(set(analytic) - set(rendered))),
        unpaired_rendered=tuple(sorted(set(rendered) - set(analytic))),
    )


def vision_comparisons(
    records: Sequence[EpisodeRecord], pairs: Sequence[tuple[str, str]] | None = None
) -> list[VisionComparison]:
    """Every agent x twin pair with a seed evaluated in both scenarios, pair by pair in the
    order the scenarios first appear in ``records``, agents likewise.

    Args:
        records: the report's episodes.
        pairs: the (analytic, rendered) scenario pairs; None for :func:`rendered_twins` of the
            scenarios in ``records``.
    """
    if pairs is None:
        pairs = rendered_twins(r.scenario for r in records)
    cells = _by_seed(records)
    agents = list(dict.fromkeys(r.agent for r in records))
    out = []
    for x, x_rendered in pairs:
        for agent in agents:
            analytic = cells.get((agent, x), {})
            rendered = cells.get((agent, x_rendered), {})
            if set(analytic) & set(rendered):
                out.append(compare(agent, analytic, rendered, (x, x_rendered)))
    return out


def left_out_text(comparisons: Sequence[VisionComparison]) -> str:
    """One sentence naming the seeds evaluated in one scenario of a pair only ("" if none)."""
    parts = []
    for c in comparisons:
        for scenario, seeds in (
            (c.analytic, c.unpaired_analytic),
            (c.rendered, c.unpaired_rendered),
        ):
            if seeds:
                shown = ", ".join(map(str, seeds[:5])) + (", ..." if len(seeds) > 5 else "")
                count = f"{len(seeds)} seed{'s' if len(seeds) > 1 else ''}"
                parts.append(f"{c.agent}: {count} of {scenario} only ({shown})")
    if not parts:
        return ""
    return "Left out, evaluated in one scenario of the pair only: " + "; ".join(parts) + "."


ESTIMATES = (
    "capture_rate_analytic",
    "capture_rate_rendered",
    "capture_rate_difference",
    "ratio_median_analytic",
    "ratio_median_rendered",
    "ratio_difference",
)


def comparison_row(c: VisionComparison) -> dict[str, Any]:
    """One entry of ``results.json``'s ``vision`` list: counts, each estimate as ``name``,
    ``name_low``, ``name_high``, and the unpaired seeds."""
    row: dict[str, Any] = {
        "agent": c.agent,
        "analytic": c.analytic,
        "rendered": c.rendered,
        "seeds": c.seeds,
        "captured_analytic": c.captured_analytic,
        "captured_rendered": c.captured_rendered,
        "only_analytic": c.only_analytic,
        "only_rendered": c.only_rendered,
        "both_captured": c.both_captured,
    }
    for name in ESTIMATES:
        est: Estimate = getattr(c, name)
        row[name], row[f"{name}_low"], row[f"{name}_high"] = est.value, est.low, est.high
    row["capture_rate_difference_interval"] = "paired percentile bootstrap over seeds"
    row["unpaired_analytic"] = list(c.unpaired_analytic)
    row["unpaired_rendered"] = list(c.unpaired_rendered)
    return row
