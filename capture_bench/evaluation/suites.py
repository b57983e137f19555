"""Leaderboard suites: YAML files under ``configs/suites/`` validated once into :class:`Suite`.

A suite file::

    description: every scenario, every built-in agent, the published seeds
    agents: [incremental_ik, pure_pursuit, ..., "models/*"]   # specs, see agents_loading
    scenarios: all               # or a list of scenario names
    episodes: 100                # first N published evaluation seeds of each scenario
    reference: incremental_ik    # agent of the paired comparison

The suite's name is its file stem. Scenario and agent names are checked against what exists when
the evaluation is planned; this module checks the file's shape and types.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from capture_bench.evaluation.errors import SuiteError
from capture_bench.task.scenarios import CONFIG_DIR

SUITES_DIR = CONFIG_DIR / "suites"
ALL = "all"


@dataclass(frozen=True)
class Suite:
    """A validated suite.

    Attributes:
        name: the file stem (``default``, ``quick``), or ``custom-<hash>`` for a narrowed
            selection (:func:`narrow`); reports go to ``reports/<name>/``.
        description: one line for people.
        agents: agent specs, in report order.
        scenarios: scenario names, in report order; ``("all",)`` means every shipped scenario.
        episodes: episodes per agent x scenario = the first ``episodes`` published evaluation
            seeds of each scenario.
        reference: the agent every other one is compared with, seed by seed.
        path: the file it came from.
        sha256: hash of the file's bytes (provenance).
    """

    name: str
    description: str
    agents: tuple[str, ...]
    scenarios: tuple[str, ...]
    episodes: int
    reference: str
    path: Path
    sha256: str


_KEYS = ("description", "agents", "scenarios", "episodes", "reference")


def list_suites(suites_dir: Path = SUITES_DIR) -> list[str]:
    """Names of the shipped suites, sorted."""
    return sorted(p.stem for p in suites_dir.glob("*.yaml"))


def _string_list(value: Any, where: str, allow_all: bool) -> tuple[str, ...]:
    if allow_all and value == ALL:
        return (ALL,)
    if not isinstance(value, list) or not value or not all(isinstance(v, str) and v for v in value):
        also = f" or {ALL!r}" if allow_all else ""
        raise SuiteError(f"{where}: {value!r} should be a non-empty list of names{also}")
    return tuple(dict.fromkeys(value))


def load_suite(name_or_path: str | Path, suites_dir: Path = SUITES_DIR) -> Suite:
    """Load and validate a shipped suite by name, or any suite YAML by path."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = suites_dir / f"{name_or_path}.yaml"
        if not path.is_file():
            valid = ", ".join(list_suites(suites_dir)) or "none"
            raise SuiteError(f"unknown suite {str(name_or_path)!r}; valid suites: {valid}")
    if not path.is_file():
        raise SuiteError(f"{path}: no such suite file")
    raw = path.read_bytes()
    try:
        data = yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0]
        raise SuiteError(f"{path}: invalid YAML ({first})") from None
    if not isinstance(data, dict):
        raise SuiteError(f"{path}: expected a mapping with keys {', '.join(_KEYS)}")
    unknown = sorted(set(data) - set(_KEYS))
    if unknown:
        raise SuiteError(f"{path}: unknown key {unknown[0]!r}; valid keys: {', '.join(_KEYS)}")
    for key in ("agents", "scenarios", "episodes"):
        if key not in data:
            raise SuiteError(f"{path}: missing key {key!r}")
    episodes = data["episodes"]
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise SuiteError(f"{path}: key 'episodes' is {episodes!r}; expected a whole number >= 1")
    reference = data.get("reference", "incremental_ik")
    if not isinstance(reference, str) or not reference:
        raise SuiteError(f"{path}: key 'reference' is {reference!r}; expected an agent name")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise SuiteError(f"{path}: key 'description' is {description!r}; expected a string")
    return Suite(
        name=path.stem,
        description=description,
        agents=_string_list(data["agents"], f"{path}: key 'agents'", allow_all=False),
        scenarios=_string_list(data["scenarios"], f"{path}: key 'scenarios'", allow_all=True),
        episodes=episodes,
        reference=reference,
        path=path,
        sha256=hashlib.sha256(raw).hexdigest(),
    )


def narrow(
    suite: Suite,
    agents: list[str] | None = None,
    scenarios: list[str] | None = None,
    episodes: int | None = None,
) -> Suite:
    """The suite with its agents, scenarios or episode count replaced (``--agents`` etc.).

    A selection that differs from the suite as defined is not that suite: it is named
    ``custom-<8 hex digits of the selection's hash>`` (so its report goes to its own folder,
    ``<out>/custom-<hash>/``, and never replaces ``<out>/<suite>/``) and its description says
    what it was narrowed from. The same selection always gets the same name.
    """
    if episodes is not None and episodes < 1:
        raise SuiteError(f"--episodes {episodes}: expected a whole number >= 1")
    changes: dict[str, Any] = {}
    if agents:
        changes["agents"] = tuple(dict.fromkeys(agents))
    if scenarios:
        changes["scenarios"] = tuple(dict.fromkeys(scenarios))
    if episodes is not None:
        changes["episodes"] = episodes
    narrowed = dataclasses.replace(suite, **changes)
    if (narrowed.agents, narrowed.scenarios, narrowed.episodes) == (
        suite.agents,
        suite.scenarios,
        suite.episodes,
    ):
        return narrowed
    selection = json.dumps(
        [suite.name, suite.sha256, narrowed.agents, narrowed.scenarios, narrowed.episodes]
    )
    digest = hashlib.sha256(selection.encode()).hexdigest()[:8]
    described = (
        f"custom selection from the {suite.name!r} suite: agents {', '.join(narrowed.agents)}; "
        f"scenarios {', '.join(narrowed.scenarios)}; {narrowed.episodes} episodes each"
    )
    return dataclasses.replace(narrowed, name=f"custom-{digest}", description=described)
