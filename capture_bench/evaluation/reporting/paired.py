"""Two sets of episodes on the same seeds, compared seed by seed: the report's paired sections.

A comparison has two sides, A (the baseline) and B, that share everything but one thing: the same
agent on a scenario and on its rendered twin (`capture_bench.evaluation.reporting.vision`), or two
agents, one fed by the estimator and one by the camera's pixels, on one scenario
(`capture_bench.evaluation.reporting.pixel_comparison`). On the seeds evaluated on both sides
(`compare`; a seed evaluated on one side only is left out and named):

* capture rate of each side, Wilson 95% interval;
* their difference, B minus A: the mean over seeds of (captured by B) - (captured by A), each term
  -1, 0 or +1, with a 95% percentile bootstrap interval resampling the seeds (paired); the seeds
  captured by one side only (McNemar's discordant pairs) are counted beside it;
* median ratio of capture time to the physical limit of each side, over its captured episodes,
  bootstrap interval;
* paired ratio difference: the median over seeds captured by both of (B's ratio - A's ratio),
  bootstrap interval over those seeds; positive is slower on side B.

The intervals are `bootstrap_estimate`'s and
`wilson_interval`'s, as in the rest of the report.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from capture_bench.evaluation.reporting.metrics import Estimate, bootstrap_estimate, wilson_interval
from capture_bench.evaluation.running.rollout import EpisodeRecord


@dataclass(frozen=True)
class Paired:
    """Side A and side B on the seeds evaluated on both.

    Attributes:
        subject: what both sides share (the agent, or the scenario).
        a, b: the two sides' names (scenarios, or agents).
        seeds: number of seeds evaluated on both sides, the pairs every figure is computed on.
        captured_a, captured_b: captures among those seeds on each side.
        capture_rate_a, capture_rate_b: share captured, Wilson 95% interval.
        capture_rate_difference: B minus A share, paired bootstrap interval.
        only_a, only_b, both_captured: seeds captured by side A only, by B only, by both.
        ratio_median_a, ratio_median_b: median capture time / physical limit over the captured
            episodes of the paired seeds, bootstrap interval.
        ratio_difference: median over the seeds captured by both of (B's ratio - A's ratio),
            bootstrap interval; positive is slower on side B.
        unpaired_a, unpaired_b: seeds evaluated on that side only, sorted; left out of every
            figure.
    """

    subject: str
    a: str
    b: str
    seeds: int
    captured_a: int
    captured_b: int
    capture_rate_a: Estimate
    capture_rate_b: Estimate
    capture_rate_difference: Estimate
    only_a: int
    only_b: int
    both_captured: int
    ratio_median_a: Estimate
    ratio_median_b: Estimate
    ratio_difference: Estimate
    unpaired_a: tuple[int, ...] = ()
    unpaired_b: tuple[int, ...] = ()


#: The comparison's estimates, each written as ``name``, ``name_low``, ``name_high``.
ESTIMATES = (
    "capture_rate_a",
    "capture_rate_b",
    "capture_rate_difference",
    "ratio_median_a",
    "ratio_median_b",
    "ratio_difference",
)


def by_seed(records: Iterable[EpisodeRecord]) -> dict[tuple[str, str], dict[int, EpisodeRecord]]:
    """The records of each (agent, scenario), by seed."""
    cells: dict[tuple[str, str], dict[int, EpisodeRecord]] = {}
    for r in records:
        cells.setdefault((r.agent, r.scenario), {})[r.seed] = r
    return cells


def compare(
    subject: str,
    a: dict[int, EpisodeRecord],
    b: dict[int, EpisodeRecord],
    names: tuple[str, str],
) -> Paired:
    """The comparison of side A's and side B's episodes by seed (``names``: A's and B's); at
    least one seed must be on both sides."""
    seeds = sorted(set(a) & set(b))
    if not seeds:
        raise ValueError(f"{subject}: no seed evaluated on both {names[0]} and {names[1]}")
    got_a = np.array([a[s].captured for s in seeds], dtype=float)
    got_b = np.array([b[s].captured for s in seeds], dtype=float)
    both = (got_a == 1) & (got_b == 1)
    ratio_a = np.array([a[s].ratio if a[s].captured else math.nan for s in seeds])
    ratio_b = np.array([b[s].ratio if b[s].captured else math.nan for s in seeds])
    return Paired(
        subject=subject,
        a=names[0],
        b=names[1],
        seeds=len(seeds),
        captured_a=int(got_a.sum()),
        captured_b=int(got_b.sum()),
        capture_rate_a=wilson_interval(int(got_a.sum()), len(seeds)),
        capture_rate_b=wilson_interval(int(got_b.sum()), len(seeds)),
        capture_rate_difference=bootstrap_estimate(got_b - got_a, "mean"),
        only_a=int(((got_a == 1) & (got_b == 0)).sum()),
        only_b=int(((got_a == 0) & (got_b == 1)).sum()),
        both_captured=int(both.sum()),
        ratio_median_a=bootstrap_estimate(ratio_a, "median"),
        ratio_median_b=bootstrap_estimate(ratio_b, "median"),
        # a ratio that is not finite (no finite bound) drops out, as in every ratio figure
        ratio_difference=bootstrap_estimate(ratio_b[both] - ratio_a[both], "median"),
        unpaired_a=tuple(sorted(set(a) - set(b))),
        unpaired_b=tuple(sorted(set(b) - set(a))),
    )


def left_out_text(comparisons: Sequence[Paired], phrase: str = "on one side only") -> str:
    """One sentence naming the seeds evaluated on one side only ("" if none): "Left out,
    evaluated ``phrase``: ..."."""
    parts = []
    for c in comparisons:
        for side, seeds in ((c.a, c.unpaired_a), (c.b, c.unpaired_b)):
            if seeds:
                shown = ", ".join(map(str, seeds[:5])) + (", ..." if len(seeds) > 5 else "")
                count = f"{len(seeds)} seed{'s' if len(seeds) > 1 else ''}"
                parts.append(f"{c.subject}: {count} of {side} only ({shown})")
    if not parts:
        return ""
    return f"Left out, evaluated {phrase}: " + "; ".join(parts) + "."


def comparison_row(c: Paired, keys: tuple[str, str, str]) -> dict[str, Any]:
    """One entry of a ``results.json`` list: the subject and the two sides under ``keys``
    (e.g. ``("agent", "analytic", "rendered")``), the counts, and each estimate as ``name``,
    ``name_low``, ``name_high``, with ``_a`` / ``_b`` in the names replaced by the sides' keys."""
    subject, a, b = keys

    def named(name: str) -> str:
        side = {"_a": a, "_b": b}.get(name[-2:])
        return name if side is None else f"{name[:-2]}_{side}"

    row: dict[str, Any] = {
        subject: c.subject,
        a: c.a,
        b: c.b,
        "seeds": c.seeds,
        f"captured_{a}": c.captured_a,
        f"captured_{b}": c.captured_b,
        f"only_{a}": c.only_a,
        f"only_{b}": c.only_b,
        "both_captured": c.both_captured,
    }
    for name in ESTIMATES:
        est: Estimate = getattr(c, name)
        key = named(name)
        row[key], row[f"{key}_low"], row[f"{key}_high"] = est.value, est.low, est.high
    row["capture_rate_difference_interval"] = "paired percentile bootstrap over seeds"
    row[f"unpaired_{a}"] = list(c.unpaired_a)
    row[f"unpaired_{b}"] = list(c.unpaired_b)
    return row


@dataclass(frozen=True)
class PairedSection:
    """A paired section of the report.

    Attributes:
        title: its heading; text: the paragraph under it (what the figures mean).
        key: its list's key in ``results.json``; columns: (subject, A, B) key words of its rows.
        header: the table's column names.
        tables: (table title, comparisons) in order.
        left_out: the sentence naming the seeds left out ("" if none).
        first: the attribute of a comparison its row is labelled by (``subject`` or ``a``).
    """

    title: str
    text: str
    key: str
    columns: tuple[str, str, str]
    header: tuple[str, ...]
    tables: list[tuple[str, list[Paired]]]
    left_out: str
    first: str = "subject"

    def rows(self) -> list[dict[str, Any]]:
        """The section's entries of ``results.json``."""
        return [comparison_row(c, self.columns) for _, cs in self.tables for c in cs]


def header(a: str, b: str, first: str) -> tuple[str, ...]:
    """A paired table's column names, sides labelled ``a`` and ``b``, rows by ``first``."""
    return (
        first,
        "paired seeds",
        f"capture rate, {a}",
        f"capture rate, {b}",
        "Δ capture rate",
        f"captured by {a} only / {b} only / both",
        f"median ratio, {a}",
        f"median ratio, {b}",
        "paired Δ ratio",
    )
