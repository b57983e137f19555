"""A report folder that ``evaluate.py`` wrote, read back: `read_report`.

Its episodes come from ``episodes.csv`` (`read_episodes`,
every field exact), what they were played on from ``results.json``'s provenance; the fields a
merge (`capture_bench.evaluation.reporting.merge`) reads are checked for their types, and the
episodes against the agents and seeds the provenance names. Anything else is an `EvaluationError`
of one line naming the file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from capture_bench.evaluation.errors import EvaluationError
from capture_bench.evaluation.reporting.report import TWINS_CSV, read_episodes
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.provenance import display_path

#: What a report folder must hold to be read back.
RESULTS, EPISODES = "results.json", "episodes.csv"
PACKAGE = "capture-bench"
EpisodeKey = tuple[str, str, int]  # (agent, scenario, seed)


@dataclass(frozen=True)
class SourceReport:
    """One report folder read back.

    Attributes:
        directory: the folder.
        suite: its suite name (``default``, ``custom-<hash>``, ``merged-<hash>``).
        reference: the agent of its paired comparisons.
        provenance: its ``results.json`` provenance as written (``seeds``: scenario -> the
            published seeds played; ``config_hashes``: ``scenarios`` and ``models``; ``agents``:
            label, spec, kind, privileged; ``packages``; ``git``).
        records: its episodes, in the file's order.
        twin_records: its episodes on the scenarios' twins (``twin_episodes.csv``, where it has
            one), not ranked.
    """

    directory: Path
    suite: str
    reference: str
    provenance: dict[str, Any]
    records: list[EpisodeRecord]
    twin_records: list[EpisodeRecord] = field(default_factory=list)

    @property
    def name(self) -> str:
        """The folder as messages and the merged provenance name it."""
        return display_path(self.directory)

    @property
    def seeds(self) -> dict[str, list[int]]:
        """Scenario (as named in the evaluation) -> the seeds played, in order."""
        return self.provenance["seeds"]

    @property
    def agents(self) -> list[dict[str, Any]]:
        """The agents evaluated, in order: ``label``, ``spec``, ``kind``, ``privileged``."""
        return self.provenance["agents"]

    def hashes(self, kind: str) -> dict[str, Any]:
        """``config_hashes[kind]``: scenario -> file sha256, or model label -> its entry."""
        return self.provenance["config_hashes"][kind]

    @property
    def version(self) -> str | None:
        """The capture-bench version that played the episodes."""
        return self.provenance["packages"].get(PACKAGE)

    @property
    def commit(self) -> str | None:
        """The git commit that played the episodes (None where git named none)."""
        return self.provenance["git"].get("commit")


def read_report(directory: Path) -> SourceReport:
    """The report in ``directory``; raises `EvaluationError` if it is no report that
    ``evaluate.py`` wrote or a file of it cannot be read."""
    directory = Path(directory)
    if not directory.is_dir():
        raise EvaluationError(f"{directory}: no such report folder")
    for name in (RESULTS, EPISODES):
        if not (directory / name).is_file():
            raise EvaluationError(
                f"{directory}: not a report folder written by evaluate.py (no {name})"
            )
    path = directory / RESULTS
    try:
        payload = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise EvaluationError(f"{path}: cannot be read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise EvaluationError(f"{path}: not valid JSON ({exc})") from None
    twins = directory / TWINS_CSV
    report = SourceReport(
        directory,
        *_checked_results(payload, path),
        read_episodes(directory / EPISODES),
        read_episodes(twins) if twins.is_file() else [],
    )
    _check_episodes(report)
    return report


def _checked_results(payload: Any, path: Path) -> tuple[str, str, dict[str, Any]]:
    """``(suite, reference, provenance)`` of a ``results.json``, the fields a merge reads checked
    for their types."""

    def refuse(what: str) -> EvaluationError:
        return EvaluationError(f"{path}: {what}; not a results.json written by evaluate.py")

    def get(mapping: Any, key: str, kind: type, where: str = "") -> Any:
        value = mapping.get(key) if isinstance(mapping, dict) else None
        if not isinstance(value, kind):
            raise refuse(f"{where}{key!r} is missing or not a {kind.__name__}")
        return value

    provenance = get(payload, "provenance", dict)
    suite, reference = get(payload, "suite", str), get(payload, "reference", str)
    for key, kind in (("seeds", dict), ("agents", list), ("packages", dict), ("git", dict)):
        get(provenance, key, kind, "provenance ")
    if not isinstance(provenance["git"].get("commit"), str | None):
        raise refuse("provenance git 'commit' is not a string")
    hashes = get(provenance, "config_hashes", dict, "provenance ")
    for key in ("scenarios", "models"):
        get(hashes, key, dict, "config_hashes ")
    for label in hashes["models"]:
        get(hashes["models"], label, dict, "config_hashes models ")
    for scenario, seeds in provenance["seeds"].items():
        if not isinstance(seeds, list) or not all(type(s) is int for s in seeds):
            raise refuse(f"the seeds of {scenario!r} are not a list of whole numbers")
    for agent in provenance["agents"]:
        get(agent, "label", str, "an agent's ")
        get(agent, "kind", str, "an agent's ")
        get(agent, "privileged", bool, "an agent's ")
    return suite, reference, provenance


def _check_episodes(report: SourceReport) -> None:
    """Refuse an ``episodes.csv`` that does not hold exactly its agents' episodes on the seeds
    its ``results.json`` names, in the evaluation's order."""
    where = f"{report.directory / EPISODES}: not the episodes of {report.directory / RESULTS}"
    if not report.records:
        raise EvaluationError(f"{report.directory / EPISODES}: holds no episode")
    labels = list(dict.fromkeys(r.scenario for r in report.records))
    if len(labels) != len(report.seeds):
        raise EvaluationError(f"{where} ({len(labels)} scenarios, not {len(report.seeds)})")
    expected = [
        (agent["label"], label, seed)
        for agent in report.agents
        for label, seeds in zip(labels, report.seeds.values())
        for seed in seeds
    ]
    found = [(r.agent, r.scenario, r.seed) for r in report.records]
    if found != expected:
        pair = next(((f, e) for f, e in zip(found, expected) if f != e), None)
        detail = f"{len(found)} episodes, not {len(expected)}"
        if pair is not None:
            detail = f"{episode_text(pair[0])} where {episode_text(pair[1])} belongs"
        raise EvaluationError(f"{where} ({detail})")


def episode_text(key: EpisodeKey) -> str:
    """``pure_pursuit on paper seed 1000000``."""
    agent, scenario, seed = key
    return f"{agent} on {scenario} seed {seed}"
