"""Pixels against the estimate: a policy that sees the camera's image beside those fed by the
estimator, on the same scenario and seeds.

A trained model whose ``observation_source`` is ``pixels`` (the report's provenance says so) sees
the eye-to-hand camera's image and the arm's state, no estimate. On each scenario it is compared
seed by seed (`compare`: side A the estimate-fed agent,
side B the pixel-fed one) with the report's reference (the paper's incremental_ik) and with every
trained model fed by the estimator, on the seeds both were evaluated on; a positive Δ capture
rate is the pixel policy capturing more, a positive paired Δ ratio it being slower.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from capture_bench.evaluation.reporting import paired
from capture_bench.evaluation.reporting.paired import Paired, PairedSection
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.sensing.sources import PIXELS

TITLE = "Pixels vs the estimate"
#: Said under the section's title, in both the Markdown and the HTML report.
TEXT = (
    "Each policy trained on the camera's pixels (no estimator: the image and the arm's state) "
    "beside the reference and the policies fed by the estimator, on the same scenario and "
    "seeds: Δ capture rate is the pixel policy's minus the other agent's over the "
    "seeds both were evaluated on (a seed counts -1, 0 or +1; 95% paired percentile bootstrap "
    "over seeds), next to the seeds captured by one agent only, and paired Δ ratio is the median "
    "over seeds captured by both of the pixel policy's minus the other's ratio of capture time "
    "to the physical limit (positive: the pixel policy is slower)."
)
#: ``results.json``'s ``pixels`` entries name the scenario and the two agents by these keys.
COLUMNS = ("scenario", "estimate_agent", "pixel_agent")
HEADER = paired.header("estimate-fed", "pixel-fed", "estimate-fed agent")


def pixel_agents(models: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The report's models that see pixels: ``models`` is the provenance's label -> entry."""
    return [label for label, m in models.items() if m.get("trained_observation_source") == PIXELS]


def pixel_comparisons(
    records: Sequence[EpisodeRecord], reference: str, models: Mapping[str, Mapping[str, Any]]
) -> list[Paired]:
    """Every pixel model against the reference and each estimate-fed model, per scenario (in
    the order scenarios first appear in ``records``), where they share a seed."""
    pixels = pixel_agents(models)
    others = [reference, *(label for label in models if label not in pixels)]
    cells = paired.by_seed(records)
    out = []
    for scenario in dict.fromkeys(r.scenario for r in records):
        for pixel in pixels:
            for other in dict.fromkeys(others):
                a, b = cells.get((other, scenario), {}), cells.get((pixel, scenario), {})
                if set(a) & set(b):
                    out.append(paired.compare(scenario, a, b, (other, pixel)))
    return out


def section(
    records: Sequence[EpisodeRecord], reference: str, models: Mapping[str, Mapping[str, Any]]
) -> PairedSection | None:
    """The report's section, one table per scenario and pixel model; None where the report
    holds no pixel model beside another agent."""
    comparisons = pixel_comparisons(records, reference, models)
    if not comparisons:
        return None
    tables: dict[str, list[Paired]] = {}
    for c in comparisons:
        tables.setdefault(f"{c.subject}: {c.b}", []).append(c)
    left_out = paired.left_out_text(comparisons, "by one agent only")
    tables_in_order = list(tables.items())
    return PairedSection(TITLE, TEXT, "pixels", COLUMNS, HEADER, tables_in_order, left_out, "a")
