"""Merge reports that ``evaluate.py`` wrote, for example one agent per machine, into one report.

Each folder is read back by `read_report`.
`check_mergeable` refuses reports that did not play the same game: other scenarios or
scenario files, other seeds, another reference agent, another capture-bench version or git
commit, or one agent label for another agent (kind, privilege, a model's files);
`merge_records` refuses an episode (agent, scenario, seed) that two reports hold with other
values and keeps identical ones once. `plan_merge` puts the episodes in the order one
evaluation of every agent writes them (agents in order of first appearance, then scenario, then
seed) and aggregates them as the evaluation does, so the merged tables are those of one
evaluation of every agent. Every refusal is an `EvaluationError` of one line, raised
before anything is written.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Hashable, Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from capture_bench import rliable_stats
from capture_bench.evaluation.errors import EvaluationError
from capture_bench.evaluation.reporting.aggregate import rank_agents, summarise_all
from capture_bench.evaluation.reporting.report import ReportData, csv_value
from capture_bench.evaluation.reporting.report_folder import (
    PACKAGE,
    EpisodeKey,
    SourceReport,
    episode_text,
    read_report,
)
from capture_bench.evaluation.reporting.watch import choose_episodes
from capture_bench.evaluation.running.rollout import EPISODE_COLUMNS, TIMING_COLUMNS, EpisodeRecord
from capture_bench.evaluation.running.suites import VALIDATION_NOTE, VALIDATION_SUFFIX
from capture_bench.evaluation.running.video import EpisodeVideo
from capture_bench.files import check_writable, episode_file_name
from capture_bench.provenance import git_state

#: The provenance of each source report that the merged report keeps.
SOURCE_KEYS = ("command", "git", "packages", "machine", "backend", "timing", "merged_from")


def check_mergeable(reports: Sequence[SourceReport]) -> list[str]:
    """Refuse (`EvaluationError`, naming the report and the mismatch) reports that did
    not play the same scenario files on the same seeds with the same reference agent and the same
    code (capture-bench version and git commit), or that name one agent differently (kind,
    privileged, a model's file hashes). Returns notes for the user: a source computed with
    uncommitted changes, a merge made at another commit than the sources'."""
    first = reports[0]
    for other in reports[1:]:
        _same_scenarios(first, other)
        _same_code(first, other)
        if other.reference != first.reference:
            raise EvaluationError(
                f"{other.name}: reference agent {other.reference!r}, but {first.name}'s is "
                f"{first.reference!r}; merge reports of one reference"
            )
    _same_agents(reports)
    notes = [
        f"{r.name} was computed with uncommitted changes (the merged report says dirty: true)"
        for r in reports
        if r.provenance["git"].get("dirty")
    ]
    here = str(git_state().get("commit") or "")
    if here and first.commit and here != first.commit:
        notes.append(
            f"this checkout is at commit {here[:12]}, the episodes were played at "
            f"{first.commit[:12]}: the tables are aggregated by this checkout's code"
        )
    return notes


def _same_scenarios(first: SourceReport, other: SourceReport) -> None:
    if set(other.seeds) != set(first.seeds):
        raise EvaluationError(
            f"{other.name}: scenarios {', '.join(other.seeds)}, but {first.name}: "
            f"{', '.join(first.seeds)}; merge reports of the same scenarios"
        )
    for scenario, seeds in first.seeds.items():
        expected = first.hashes("scenarios").get(scenario)
        found = other.hashes("scenarios").get(scenario)
        if found != expected:
            raise EvaluationError(
                f"{other.name}: scenario {scenario!r} is another file than in {first.name} "
                f"(sha256 {str(found)[:12]} vs {str(expected)[:12]}); merge reports of the same "
                "scenario files"
            )
        played = other.seeds[scenario]
        if played != seeds:
            raise EvaluationError(
                f"{other.name}: scenario {scenario!r} played on {_seeds_text(played)}, "
                f"but {first.name} on {_seeds_text(seeds)}; merge reports of the same seeds "
                "(the same --episodes)"
            )


def _seeds_text(seeds: list[int]) -> str:
    """``3 seeds (1000000 to 1000002)``."""
    if not seeds:
        return "no seeds"
    return f"{len(seeds)} seeds ({seeds[0]} to {seeds[-1]})"


def _same_code(first: SourceReport, other: SourceReport) -> None:
    if other.version != first.version:
        raise EvaluationError(
            f"{other.name}: {PACKAGE} {other.version}, but {first.name}: {first.version}; merge "
            "reports of the same version"
        )
    if other.commit != first.commit:
        raise EvaluationError(
            f"{other.name}: computed at commit {other.commit or 'unknown'}, but {first.name} at "
            f"{first.commit or 'unknown'}; merge reports of the same commit (check it out on "
            "every machine and evaluate again)"
        )


def _same_agents(reports: Sequence[SourceReport]) -> None:
    """Refuse an agent label that two reports give another kind, privilege or model files."""
    seen: dict[str, tuple[SourceReport, dict[str, Any]]] = {}
    for report in reports:
        for agent in report.agents:
            label = agent["label"]
            if label not in seen:
                seen[label] = (report, agent)
                continue
            before, known = seen[label]
            for key in ("kind", "privileged"):
                if agent[key] != known[key]:
                    raise EvaluationError(
                        f"{report.name}: agent {label!r} has {key} {agent[key]!r}, but in "
                        f"{before.name} {known[key]!r}"
                    )
            files = report.hashes("models").get(label, {}).get("sha256")
            if files != before.hashes("models").get(label, {}).get("sha256"):
                raise EvaluationError(
                    f"{report.name}: model {label!r} is not the files of {before.name}'s "
                    "(config_hashes.models sha256 differ); merge reports of the same model files"
                )


def episode_cells(record: EpisodeRecord) -> dict[str, Any]:
    """An episode's columns as ``episodes.csv`` writes them, the timing columns left out."""
    return {c: csv_value(getattr(record, c)) for c in EPISODE_COLUMNS if c not in TIMING_COLUMNS}


def merge_records(reports: Sequence[SourceReport], twins: bool = False) -> list[EpisodeRecord]:
    """Every episode of ``reports`` once (with ``twins``: every episode on the scenarios'
    twins, ``SourceReport.twin_records``), in the order one evaluation of all their agents writes
    them: agents in order of first appearance across ``reports``, then scenarios, then seeds in
    the order played. An episode in two reports is kept once if its columns (timing aside) are
    the same to the last digit; else `EvaluationError` names the two reports, the episode
    and a column that differs."""
    kept: dict[EpisodeKey, tuple[EpisodeRecord, SourceReport]] = {}
    for report in reports:
        for record in report.twin_records if twins else report.records:
            key = (record.agent, record.scenario, record.seed)
            if key not in kept:
                kept[key] = (record, report)
                continue
            earlier, source = kept[key]
            mine, theirs = episode_cells(earlier), episode_cells(record)
            column = next((c for c in mine if mine[c] != theirs[c]), None)
            if column is not None:
                raise EvaluationError(
                    f"{report.name} and {source.name} disagree on the episode of "
                    f"{episode_text(key)} ({column}: {theirs[column]!r} vs {mine[column]!r}); "
                    "merge only one of them"
                )
    records = [record for record, _ in kept.values()]
    agents = _positions(r.agent for r in records)
    scenarios = _positions(r.scenario for r in records)
    seeds = _positions((r.scenario, r.seed) for r in records)
    return sorted(
        records, key=lambda r: (agents[r.agent], scenarios[r.scenario], seeds[r.scenario, r.seed])
    )


def _positions(items: Iterable[Hashable]) -> dict[Any, int]:
    """Each item -> the position of its first appearance."""
    return {item: k for k, item in enumerate(dict.fromkeys(items))}


def merged_name(reports: Sequence[SourceReport]) -> str:
    """``merged-<8 hex digits>``: a hash of the sources' suites and agents, in order, so that
    merging the same reports again replaces the same folder."""
    sources = [[r.suite, [a["label"] for a in r.agents]] for r in reports]
    suffix = VALIDATION_SUFFIX if _seed_set(reports[0]) == "validation" else ""
    return f"merged-{hashlib.sha256(json.dumps(sources).encode()).hexdigest()[:8]}{suffix}"


def _seed_set(report: SourceReport) -> str:
    """The seeds a report played, ``evaluation`` or ``validation`` (reports from before the
    choice existed played the evaluation seeds)."""
    return str(report.provenance.get("seed_set", "evaluation"))


def merged_agents(reports: Sequence[SourceReport]) -> list[dict[str, Any]]:
    """Every agent once, in order of first appearance, as its first report names it."""
    agents: dict[str, dict[str, Any]] = {}
    for report in reports:
        for agent in report.agents:
            agents.setdefault(agent["label"], agent)
    return list(agents.values())


def carried_videos(
    reports: Sequence[SourceReport], data: ReportData, learned: set[str]
) -> tuple[list[EpisodeVideo], str]:
    """The merged report's episodes to watch (`choose_episodes` on the merged ranking),
    their GIFs taken from the source reports, and what the provenance says of them. If a source
    report lacks one (its suite had ``videos: false``, or it chose another seed), none is
    shown: the episodes are not played again here."""
    watches = choose_episodes(data.records, data.ranking, data.reference, learned)
    keys = [(agent, w.scenario, w.seed) for w in watches for agent in w.agents]
    if not keys:
        return [], "none: no agent to watch"
    played = {(r.agent, r.scenario, r.seed): r for r in data.records}
    videos = []
    for key in keys:
        name = episode_file_name(*key, ".gif")
        found = [r.directory / name for r in reports if (r.directory / name).is_file()]
        if not found:
            return [], f"left out: no source report holds {name}"
        try:
            gif = found[0].read_bytes()
        except OSError as exc:
            raise EvaluationError(f"{found[0]}: cannot be read ({exc.strerror or exc})") from None
        videos.append(EpisodeVideo(played[key], gif, _frames(gif, found[0])))
    return videos, f"{len(videos)} GIFs carried over from the source reports"


def _frames(gif: bytes, path: Path) -> int:
    """The number of frames of a GIF."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(gif)) as image:
            return int(getattr(image, "n_frames", 1))
    except OSError as exc:
        raise EvaluationError(f"{path}: not a GIF ({exc})") from None


def merged_provenance(
    reports: Sequence[SourceReport], command: str, records: int, videos: tuple[int, str]
) -> dict[str, Any]:
    """The merged report's provenance: the command, the sources' common code (commit, dirty if
    any source was) and packages, seeds and configuration hashes, every agent, and each source
    report (its folder, suite, command, git, packages, machine, backend, timing)."""
    first = reports[0]
    models: dict[str, Any] = {}
    for report in reports:
        for label, entry in report.hashes("models").items():
            models.setdefault(label, entry)
    agents = merged_agents(reports)
    return {
        "command": command,
        "merged_from": [
            {
                "report": r.name,
                "suite": r.suite,
                **{k: r.provenance[k] for k in SOURCE_KEYS if k in r.provenance},
            }
            for r in reports
        ],
        "git": {
            "commit": first.commit,
            "dirty": any(bool(r.provenance["git"].get("dirty")) for r in reports),
        },
        "packages": {
            name: version
            for name, version in first.provenance["packages"].items()
            if all(r.provenance["packages"].get(name) == version for r in reports)
        },
        "merged_on": {"git": git_state()},
        "config_hashes": {
            "scenarios": first.hashes("scenarios"),
            "models": {a["label"]: models[a["label"]] for a in agents if a["label"] in models},
        },
        "seed_set": _seed_set(first),
        "seeds": first.seeds,
        "agents": agents,
        "timing": {"episodes": records, "videos": videos[0]},
        "videos": videos[1],
    }


def plan_merge(
    directories: Sequence[Path], out: Path, command: str
) -> tuple[ReportData, list[str]]:
    """Read and check the reports in ``directories`` and make their merged report, for
    `write_report` to write into ``out/<suite>/``
    (``merged-<hash>``, `merged_name`).

    Raises `EvaluationError` (fewer than two folders, one named twice, a folder that is
    no report, a file that cannot be read, reports that cannot be merged) or
    [`ConfigError`][capture_bench.validation.ConfigError] (``out`` cannot be written), before
    anything
    is written.

    Returns:
        ``(the merged report, notes for the user)``.
    """
    if not rliable_stats.installed():  # the merged report's aggregate statistics
        raise EvaluationError(rliable_stats.MISSING)
    if len(directories) < 2:
        raise EvaluationError("--merge takes two or more report folders")
    resolved = [Path(d).resolve() for d in directories]
    twice = next((d for d, r in zip(directories, resolved) if resolved.count(r) > 1), None)
    if twice is not None:
        raise EvaluationError(f"--merge: {twice} is named twice")
    reports = [read_report(Path(d)) for d in directories]
    notes = check_mergeable(reports)
    records = merge_records(reports)
    check_writable(out, "--out")
    agents = merged_agents(reports)
    reference = reports[0].reference
    summaries = summarise_all(records, reference)
    ranking = rank_agents(summaries, {a["label"] for a in agents if a["privileged"]})
    scenarios = list(dict.fromkeys(r.scenario for r in records))
    description = (
        f"{len(reports)} reports merged ({', '.join(r.suite for r in reports)}): agents "
        f"{', '.join(a['label'] for a in agents)}; scenarios {', '.join(scenarios)}; "
        f"{len(next(iter(reports[0].seeds.values())))} episodes each"
    )
    if _seed_set(reports[0]) == "validation":
        description = f"{VALIDATION_NOTE} {description}"
    data = ReportData(
        merged_name(reports), description, command, reference, records, summaries, ranking, {}
    )
    learned = {a["label"] for a in agents if a["kind"] == "model"}
    videos, said = carried_videos(reports, data, learned)
    if not videos and said.startswith("left out"):
        notes.append(f"the episodes to watch are {said}; the merged report shows no GIF")
    provenance = merged_provenance(reports, command, len(records), (len(videos), said))
    twin_records = merge_records(reports, twins=True)
    return replace(data, provenance=provenance, videos=videos, twin_records=twin_records), notes
