"""What vision costs: each agent fed the camera's estimate beside itself fed the true state.

A suite with ``truth_twins`` plays every agent that acts on the estimate on each ranked scenario
``X`` (the analytic camera, photogrammetry and the EKF) and on its truth-fed twin ``X_truth``
(`capture_bench.task.scenarios.truth_twin`: the same targets and seeds, the estimator replaced
by the true target state). Seed s is the same target in both, so the two episodes differ only in
what the agent is told about it. Per agent, over the seeds of every ranked scenario it played in
both (`compare`, side A estimate-fed, side B truth-fed):

* perception gap: what the estimate costs against the truth, the truth-fed minus the
  estimate-fed capture rate (paired bootstrap over seeds; positive: captures the estimate
  loses) and the paired Δ ratio, the median over seeds captured by both of the truth-fed minus
  the estimate-fed ratio of capture time to the physical limit (negative: time the estimate
  costs; the limit is the seed's own on both sides, so this is Δt over the seed's limit);
* control gap: what the agent's control costs against the physical limit when it knows the
  target exactly, its truth-fed median ratio of capture time to the physical limit (1.00:
  as fast as physically possible), bootstrap over the truth-fed captures of the paired seeds.

With ``rendered_twins`` the same two gaps for the rendered camera: each rendered agent on
``X_rendered`` (`capture_bench.evaluation.reporting.vision`) against itself on ``X_truth``, on
the rendered episodes' seeds (side A rendered, side B truth-fed).
"""

from __future__ import annotations

from collections.abc import Sequence

from capture_bench.evaluation.reporting import paired
from capture_bench.evaluation.reporting.paired import Paired, PairedSection
from capture_bench.evaluation.reporting.vision import RENDERED_SUFFIX
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.task.scenarios import TRUTH_SUFFIX

TITLE = "What vision costs"
KEY = "vision_cost"
ESTIMATE, TRUTH = "estimate-fed", "truth-fed"
#: Said under the section's title, in both the Markdown and the HTML report.
TEXT = (
    "Each agent that acts on the estimate, fed the analytic camera's estimate (photogrammetry "
    "and the EKF: the ranked scenarios) and fed the true target state (each scenario's "
    "truth-fed twin X_truth: the same targets and seeds, not ranked), paired seed by seed over "
    "every ranked scenario. Perception gap: Δ capture rate, the truth-fed minus the "
    "estimate-fed capture rate (a seed counts -1, 0 or +1; 95% paired percentile bootstrap over "
    "seeds; positive: captures the estimate loses), and paired Δ ratio, the median over seeds "
    "captured by both of the truth-fed minus the estimate-fed ratio of capture time to the "
    "seed's physical limit (negative: time the estimate costs). Control gap: the truth-fed "
    "median ratio of capture time to the physical limit (1.00: as fast as physically possible; "
    "bootstrap over its captures), what the controller costs when it knows the target exactly. "
    "The rendered camera's tables compare the agent on X_rendered (markers found in pybullet's "
    "rendered image) with itself on X_truth in the same way, on the seeds of its rendered "
    "episodes; the section Rendered vs analytic vision compares X_rendered with X."
)
#: ``results.json``'s ``vision_cost`` entries name the agent and the two sides by these keys.
COLUMNS = ("agent", "camera", "truth")
HEADER = (
    "agent",
    "paired seeds",
    "capture rate, camera-fed",
    "capture rate, truth-fed",
    "perception gap: Δ capture rate",
    "captured camera-fed only / truth-fed only / both",
    "median ratio, camera-fed",
    "control gap: median ratio, truth-fed",
    "perception gap: paired Δ ratio",
)
#: The ranking's column beside the mean capture rate (`truth_fed_rates`).
COLUMN = "truth-fed mean capture rate"
RANKING_KEY = "truth_fed_mean_capture_rate"


def _cells(
    records: Sequence[EpisodeRecord], suffix: str = ""
) -> dict[str, dict[tuple[str, int], EpisodeRecord]]:
    """Each agent's records by (scenario as its twin's base names it, seed), of the scenarios
    named ``<X><suffix>`` (every record with ``suffix`` empty)."""
    out: dict[str, dict[tuple[str, int], EpisodeRecord]] = {}
    for r in records:
        if r.scenario.endswith(suffix):
            base = r.scenario[: len(r.scenario) - len(suffix)]
            out.setdefault(r.agent, {})[(base, r.seed)] = r
    return out


def perception_comparisons(
    records: Sequence[EpisodeRecord],
    twin_records: Sequence[EpisodeRecord],
    ranked: Sequence[str],
) -> list[Paired]:
    """Per agent with truth-fed episodes (in the order of ``records``' agents), the pooled
    comparison over the ``ranked`` scenarios' seeds it played fed both ways (side A
    estimate-fed: its record on ``X``; side B truth-fed: on ``X_truth``; a seed is the pair
    (X, seed))."""
    estimate = _cells([r for r in records if r.scenario in ranked])
    truth_fed = [r for r in twin_records if r.scenario.removesuffix(TRUTH_SUFFIX) in ranked]
    truth = _cells(truth_fed, TRUTH_SUFFIX)
    out = []
    for agent in dict.fromkeys(r.agent for r in records):
        a, b = estimate.get(agent, {}), truth.get(agent, {})
        if set(a) & set(b):
            out.append(paired.compare(agent, a, b, (ESTIMATE, TRUTH)))
    return out


def rendered_comparisons(twin_records: Sequence[EpisodeRecord]) -> list[Paired]:
    """Per rendered scenario ``X_rendered`` and agent that played it and ``X_truth`` (in the
    order of ``twin_records``), the comparison on the rendered episodes' seeds (side A
    rendered, side B truth-fed)."""
    cells = paired.by_seed(twin_records)
    out = []
    for scenario in dict.fromkeys(r.scenario for r in twin_records):
        if not scenario.endswith(RENDERED_SUFFIX):
            continue
        truth = scenario[: -len(RENDERED_SUFFIX)] + TRUTH_SUFFIX
        for agent in dict.fromkeys(r.agent for r in twin_records):
            a, b = cells.get((agent, scenario), {}), cells.get((agent, truth), {})
            b = {seed: r for seed, r in b.items() if seed in a}  # the rendered seeds
            if b:
                out.append(paired.compare(agent, a, b, (scenario, truth)))
    return out


def truth_fed_rates(
    twin_records: Sequence[EpisodeRecord], ranked: Sequence[str]
) -> dict[str, float]:
    """Per agent, its truth-fed capture rate averaged over the ranked scenarios it played
    truth-fed (equal weights, as the ranking's mean capture rate)."""
    rates: dict[str, dict[str, list[bool]]] = {}
    for r in twin_records:
        base = r.scenario[: -len(TRUTH_SUFFIX)]
        if r.scenario.endswith(TRUTH_SUFFIX) and base in ranked:
            rates.setdefault(r.agent, {}).setdefault(base, []).append(bool(r.captured))
    return {
        agent: sum(sum(c) / len(c) for c in by.values()) / len(by) for agent, by in rates.items()
    }


def ranking_cell(rates: dict[str, float], agent: str) -> str:
    """The ranking's `COLUMN` cell of ``agent`` ("—" where it played no truth-fed twin)."""
    return f"{rates[agent]:.3f}" if agent in rates else "—"


def section(
    records: Sequence[EpisodeRecord],
    twin_records: Sequence[EpisodeRecord],
    ranked: Sequence[str],
) -> PairedSection | None:
    """The report's section: one table pooled over the ranked scenarios (the analytic camera),
    then one per rendered scenario; None where no agent played a truth-fed twin."""
    pooled = perception_comparisons(records, twin_records, ranked)
    if not pooled:
        return None
    tables = [(f"Analytic camera, over the ranked scenarios ({', '.join(ranked)})", pooled)]
    rendered: dict[str, list[Paired]] = {}
    for c in rendered_comparisons(twin_records):
        rendered.setdefault(f"Rendered camera: {c.a} against {c.b}", []).append(c)
    tables += list(rendered.items())
    every = [c for _, cs in tables for c in cs]
    left_out = paired.left_out_text(every, "fed one way only")
    return PairedSection(TITLE, TEXT, KEY, COLUMNS, HEADER, tables, left_out)


def vision_records(
    records: Sequence[EpisodeRecord], twin_records: Sequence[EpisodeRecord]
) -> list[EpisodeRecord]:
    """The episodes the section Rendered vs analytic vision pairs: the rendered twin episodes,
    and the report's episodes, an agent's on ``X`` kept only on the seeds of its episodes on
    ``X_rendered`` where it played that twin on some (the first seeds of a suite's
    ``rendered_episodes``)."""
    rendered = [r for r in twin_records if r.scenario.endswith(RENDERED_SUFFIX)]
    played: dict[tuple[str, str], set[int]] = {}
    for r in rendered:
        played.setdefault((r.agent, r.scenario.removesuffix(RENDERED_SUFFIX)), set()).add(r.seed)
    kept = [r for r in records if r.seed in played.get((r.agent, r.scenario), {r.seed})]
    return [*kept, *rendered]
