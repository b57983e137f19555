"""A run of a suite beside its published report: which published values it reproduces.

The published leaderboard lives in ``reports/published/<suite>/`` (`published_dir`) and is
written only by ``python evaluate.py --publish``; a user's ``python evaluate.py`` writes its own
report and ends with this comparison. For every agent x scenario both reports hold, each of
`METRICS` is checked: the published value is **reproduced** where it lies inside the run's
95% interval for it (the interval the report prints: Wilson's for the capture rate, the
bootstrap's for the median ratio), and every other value is named with both numbers. Episodes
are compared seed by seed too: on the kind of machine that made the published report every
episode agrees bit for bit; on another CPU the last bits of the floats differ and an episode on a
knife edge can end the other way (docs/evaluation.md, Reproducibility), which the intervals
absorb.

`read_published` reads a report folder (``None`` where there is none, or it cannot be
read); `compare` needs no file, so the rule is tested on planted differences.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from capture_bench.evaluation.errors import EvaluationError
from capture_bench.evaluation.reporting.merge import episode_cells
from capture_bench.evaluation.reporting.report_folder import read_report
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.paths import CHECKOUT_DIR
from capture_bench.provenance import describe_machine, display_path, reproduction_key

#: The per-scenario values of the leaderboard that are compared: results.json column -> words.
METRICS: dict[str, str] = {
    "capture_rate": "capture rate",
    "ratio_median": "median ratio to the physical limit",
}

#: The rounding an interval's ends carry (Wilson's lower end of 0 of n is ~1e-17, not 0).
ROUNDING = 1e-9


def published_dir() -> Path:
    """The folder of the published reports: ``<checkout>/reports/published`` (the committed
    leaderboard; ``python evaluate.py --publish`` writes it, nothing else does)."""
    return CHECKOUT_DIR / "reports" / "published"


def is_inside(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies under it, links resolved (a path that does not
    exist yet is resolved as far as it exists)."""
    resolved, root = Path(path).resolve(), Path(folder).resolve()
    return resolved == root or root in resolved.parents


def json_number(value: Any) -> float:
    """A number of results.json as a float: ``"inf"``/``"-inf"`` strings and ``null`` (NaN)
    decoded, the inverse of the report's JSON encoding."""
    if value is None:
        return math.nan
    return float(value)


def _key(provenance: Mapping[str, Any]) -> dict[str, Any]:
    """A report's `reproduction_key`."""
    return reproduction_key(provenance.get("machine") or {}, provenance.get("packages") or {})


@dataclass(frozen=True)
class PublishedReport:
    """A report folder read back: its ``results.json`` and its episodes.

    Attributes:
        directory: the folder.
        results: ``results.json`` as written.
        records: the episodes of ``episodes.csv``, keyed by (agent, scenario, seed).
    """

    directory: Path
    results: dict[str, Any]
    records: dict[tuple[str, str, int], EpisodeRecord]

    @property
    def provenance(self) -> dict[str, Any]:
        return self.results.get("provenance") or {}

    def values(self) -> dict[tuple[str, str], dict[str, Any]]:
        """Each agent x scenario's row of ``results.json``."""
        return {(r["agent"], r["scenario"]): r for r in self.results.get("results", [])}

    def ranks(self) -> dict[str, int | None]:
        """Each agent's rank (None: privileged, not ranked)."""
        return {r["agent"]: r.get("rank") for r in self.results.get("ranking", [])}


def read_published(directory: Path) -> PublishedReport | None:
    """The report in ``directory``, or None where there is none or it cannot be read (a
    published report is compared with, never required)."""
    if not (Path(directory) / "results.json").is_file():
        return None
    try:
        report = read_report(Path(directory))
        results = json.loads((Path(directory) / "results.json").read_text())
    except (EvaluationError, OSError, ValueError):
        return None
    records = {(r.agent, r.scenario, r.seed): r for r in report.records}
    return PublishedReport(Path(directory), results, records)


@dataclass(frozen=True)
class ValueCheck:
    """One published value against the run's value and 95% interval."""

    agent: str
    scenario: str
    metric: str
    published: float
    value: float
    low: float
    high: float

    @property
    def reproduced(self) -> bool:
        """The published value lies inside the run's interval; where the run has no interval
        (too few captures to bootstrap a median), it equals the run's value (both NaN: nothing
        to compare, as for the median ratio of an agent that never captures)."""
        slack = ROUNDING * max(1.0, abs(self.published))  # an interval's ends carry rounding
        if math.isnan(self.low) or math.isnan(self.high):
            if math.isnan(self.published) or math.isnan(self.value):
                return math.isnan(self.published) and math.isnan(self.value)
            return self.published == self.value or abs(self.published - self.value) <= slack
        return self.low - slack <= self.published <= self.high + slack

    def describe(self) -> str:
        """``agent on scenario: capture rate 0.882 published, 0.840 here [0.760, 0.899]``."""
        return (
            f"{self.agent} on {self.scenario}: {METRICS[self.metric]} {_fmt(self.published)} "
            f"published, {_fmt(self.value)} here [{_fmt(self.low)}, {_fmt(self.high)}]"
        )


def _fmt(value: float) -> str:
    if math.isnan(value):
        return "—"
    return "∞" if math.isinf(value) else f"{value:.3f}"


@dataclass(frozen=True)
class Comparison:
    """A run against the published report of the same suite.

    Attributes:
        published: the published folder, as messages name it.
        published_machine: the machine that made it, in words.
        same_machine_kind: this run was made on the same kind of machine, with the same
            numerical packages (`reproduction_key`): its episodes should agree bit for bit.
        same_code: both were made at the same commit, from clean checkouts.
        checks: every compared value.
        only_published: agent x scenario cells the run did not play, ``agent on scenario``.
        only_run: cells the published report does not hold.
        episodes: episodes both played (same agent, scenario and seed).
        other_outcome: of those, the ones that ended otherwise (captured or not, or another
            failure), ``agent scenario seed``.
        identical: of those, the ones equal in every column but the timing ones.
        rank_changes: ``(agent, published rank, rank here)`` for every ranked agent whose rank
            differs.
        notes: what makes differences expected (other scenario files, seeds or code).
    """

    published: str
    published_machine: str
    same_machine_kind: bool
    same_code: bool
    checks: list[ValueCheck]
    only_published: list[str] = field(default_factory=list)
    only_run: list[str] = field(default_factory=list)
    episodes: int = 0
    other_outcome: list[str] = field(default_factory=list)
    identical: int = 0
    rank_changes: list[tuple[str, int | None, int | None]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def differences(self) -> list[ValueCheck]:
        return [c for c in self.checks if not c.reproduced]

    @property
    def reproduced(self) -> bool:
        """Every published value compared lies inside the run's interval, and the run played
        every cell the published report holds."""
        return not self.differences and not self.only_published


def compare(
    run: PublishedReport, published: PublishedReport, *, published_name: str | None = None
) -> Comparison:
    """``run`` (a report just written) against ``published``; see the module docstring."""
    ran, pub = run.values(), published.values()
    checks = []
    for key in (k for k in pub if k in ran):
        for metric in METRICS:
            checks.append(
                ValueCheck(
                    *key,
                    metric,
                    json_number(pub[key].get(metric)),
                    json_number(ran[key].get(metric)),
                    json_number(ran[key].get(f"{metric}_low")),
                    json_number(ran[key].get(f"{metric}_high")),
                )
            )
    both = [k for k in published.records if k in run.records]
    other = [
        f"{a} {s} {seed}"
        for a, s, seed in both
        if (run.records[(a, s, seed)].outcome, run.records[(a, s, seed)].failure)
        != (published.records[(a, s, seed)].outcome, published.records[(a, s, seed)].failure)
    ]
    identical = sum(
        episode_cells(run.records[k]) == episode_cells(published.records[k]) for k in both
    )
    run_ranks, pub_ranks = run.ranks(), published.ranks()
    rank_changes = [
        (agent, rank, run_ranks[agent])
        for agent, rank in pub_ranks.items()
        if agent in run_ranks and run_ranks[agent] != rank
    ]
    run_git, pub_git = run.provenance.get("git") or {}, published.provenance.get("git") or {}
    same_code = (
        run_git.get("commit") is not None
        and run_git.get("commit") == pub_git.get("commit")
        and not run_git.get("dirty")
        and not pub_git.get("dirty")
    )
    return Comparison(
        published=published_name or display_path(published.directory),
        published_machine=describe_machine(published.provenance),
        same_machine_kind=_key(run.provenance) == _key(published.provenance),
        same_code=same_code,
        checks=checks,
        only_published=[f"{a} on {s}" for a, s in pub if (a, s) not in ran],
        only_run=[f"{a} on {s}" for a, s in ran if (a, s) not in pub],
        episodes=len(both),
        other_outcome=other,
        identical=identical,
        rank_changes=rank_changes,
        notes=_notes(run.provenance, published.provenance),
    )


def _notes(run: Mapping[str, Any], published: Mapping[str, Any]) -> list[str]:
    """What makes differences expected: other scenario files, seeds or models."""
    notes = []
    run_hashes = (run.get("config_hashes") or {}).get("scenarios") or {}
    pub_hashes = (published.get("config_hashes") or {}).get("scenarios") or {}
    changed = sorted(s for s in run_hashes if s in pub_hashes and run_hashes[s] != pub_hashes[s])
    if changed:
        notes.append(f"scenario files differ from the published ones': {', '.join(changed)}")
    run_seeds, pub_seeds = run.get("seeds") or {}, published.get("seeds") or {}
    reseeded = sorted(s for s in run_seeds if s in pub_seeds and run_seeds[s] != pub_seeds[s])
    if reseeded:
        notes.append(f"other seeds than the published report on: {', '.join(reseeded)}")
    run_models = (run.get("config_hashes") or {}).get("models") or {}
    pub_models = (published.get("config_hashes") or {}).get("models") or {}
    retrained = sorted(
        m
        for m in run_models
        if m in pub_models and run_models[m].get("sha256") != pub_models[m].get("sha256")
    )
    if retrained:
        notes.append(f"model files differ from the published ones': {', '.join(retrained)}")
    return notes


def summary_lines(comparison: Comparison) -> list[str]:
    """The comparison for the terminal: a verdict, then each difference on its own line."""
    c = comparison
    kept = sum(check.reproduced for check in c.checks)
    cells = len({(check.agent, check.scenario) for check in c.checks})
    machine = (
        "the same kind of machine (episodes should agree bit for bit)"
        if c.same_machine_kind
        else f"another kind of machine ({c.published_machine})"
    )
    lines = [
        f"against the published report {c.published}, made on {machine}:",
        f"  reproduced {kept} of {len(c.checks)} values ({', '.join(METRICS.values())} of "
        f"{cells} agent x scenario cells): the published value inside this run's 95% interval",
        f"  episodes: {c.identical} of {c.episodes} identical, {len(c.other_outcome)} ended "
        "otherwise" + (f" ({_first(c.other_outcome)})" if c.other_outcome else ""),
    ]
    lines += [f"  differs: {check.describe()}" for check in c.differences]
    lines += [
        f"  rank: {agent} {_rank(old)} published, {_rank(new)} here"
        for agent, old, new in c.rank_changes
    ]
    if c.only_published:
        lines.append(f"  not played here: {_first(c.only_published)}")
    if c.only_run:
        lines.append(f"  not in the published report: {_first(c.only_run)}")
    lines += [f"  note: {note}" for note in c.notes]
    return lines


def _rank(rank: int | None) -> str:
    return "unranked" if rank is None else f"#{rank}"


def _first(items: Sequence[str], count: int = 5) -> str:
    shown = ", ".join(items[:count])
    return shown + (f" and {len(items) - count} more" if len(items) > count else "")


def markdown(comparison: Comparison) -> str:
    """The comparison as a page of the run's report (``reproduction.md``): the verdict, every
    difference, and every episode that ended otherwise."""
    c = comparison
    lines = ["# Against the published report", ""]
    lines += [f"- {line.strip()}" for line in summary_lines(c)[1:]]
    lines += ["", f"Published report: `{c.published}`, made on {c.published_machine}.", ""]
    lines += [
        "A published value is *reproduced* where it lies inside this run's 95% interval for it.",
        "On the kind of machine that made the published report the episodes agree bit for bit;",
        "on another CPU the last bits of the floats differ, and an episode on a knife edge can",
        "end the other way (docs/evaluation.md, Reproducibility).",
    ]
    if c.differences:
        lines += ["", "| agent | scenario | value | published | here | 95% interval here |"]
        lines += ["|---|---|---|---|---|---|"]
        lines += [
            f"| {d.agent} | {d.scenario} | {METRICS[d.metric]} | {_fmt(d.published)} | "
            f"{_fmt(d.value)} | [{_fmt(d.low)}, {_fmt(d.high)}] |"
            for d in c.differences
        ]
    if c.other_outcome:
        lines += ["", "Episodes that ended otherwise (agent, scenario, seed):", ""]
        lines += [f"- {key}" for key in c.other_outcome]
    return "\n".join(lines) + "\n"


def as_json(comparison: Comparison) -> dict[str, Any]:
    """The comparison as ``reproduction.json`` holds it."""
    c = comparison
    return {
        "published": c.published,
        "published_machine": c.published_machine,
        "same_machine_kind": c.same_machine_kind,
        "same_code": c.same_code,
        "reproduced": c.reproduced,
        "values": len(c.checks),
        "values_reproduced": sum(check.reproduced for check in c.checks),
        "differences": [
            {
                "agent": d.agent,
                "scenario": d.scenario,
                "metric": d.metric,
                "published": _json(d.published),
                "value": _json(d.value),
                "low": _json(d.low),
                "high": _json(d.high),
            }
            for d in c.differences
        ],
        "episodes": c.episodes,
        "episodes_identical": c.identical,
        "episodes_other_outcome": c.other_outcome,
        "rank_changes": [list(change) for change in c.rank_changes],
        "only_published": c.only_published,
        "only_run": c.only_run,
        "notes": c.notes,
    }


def _json(value: float) -> float | str | None:
    if math.isnan(value):
        return None
    return ("inf" if value > 0 else "-inf") if math.isinf(value) else value
