"""Leaderboard suites: YAML files under ``configs/suites/`` validated once into `Suite`.

A suite file::

    description: every scenario, every built-in agent, the published seeds
    agents: [incremental_ik, pure_pursuit, ..., "models/*"]   # specs, see agents_loading
    scenarios: all               # or a list of scenario names
    episodes: 100                # first N published evaluation seeds of each scenario
    reference: incremental_ik    # agent of the paired comparison; one of the agents
    videos: true                 # the report's "Episodes to watch" (default true)
    truth_twins: true            # each ranked scenario's truth-fed twin too (default false)
    rendered_twins: [paper_rendered]  # rendered twins of the suite's scenarios (default none)
    rendered_agents: [incremental_ik]  # the suite's agents that play them
    rendered_episodes: 10        # on the first N of the seeds (at most ``episodes``)

The twins are not ranked: the report's "What vision costs" compares each agent on them with
itself on their scenarios, seed by seed (`capture_bench.evaluation.reporting.vision_cost`).

The suite's name is its file stem, and its report goes to ``<out>/<name>/``; a suite file given
by path whose stem names a shipped suite but which is not that suite's file (``my/default.yaml``)
is named ``custom-<hash>`` instead (`shadowed_suite`), so that ``reports/default/`` only
ever holds the shipped suite. Scenario and agent names are checked against what exists when
the evaluation is planned; this module checks the file's shape and types.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from capture_bench.evaluation.errors import SuiteError
from capture_bench.task.scenarios import CONFIG_DIR
from capture_bench.validation import Rule, check_mapping, is_file, read_mapping

SUITES_DIR = CONFIG_DIR / "suites"
ALL = "all"


@dataclass(frozen=True)
class Suite:
    """A validated suite.

    Attributes:
        name: the file stem (``default``, ``quick``), or ``custom-<hash>`` for a narrowed
            selection (`narrow`) or a file named like a shipped suite that is not it
            (`shadowed_suite`); reports go to ``reports/<name>/``.
        description: one line for people.
        agents: agent specs, in report order.
        scenarios: scenario names, in report order; ``("all",)`` means every shipped scenario
            with the analytic camera (rendered ones are named: the ``vision`` suite).
        episodes: episodes per agent x scenario = the first ``episodes`` published evaluation
            seeds of each scenario.
        reference: the agent every other one is compared with, seed by seed.
        path: the file it came from.
        sha256: hash of the file's bytes (provenance).
        videos: the report shows, for each scenario, the reference and the best-ranked trained
            model on one seed as animated GIFs (`capture_bench.evaluation.reporting.watch`); they
            are run again with rendering after the evaluation.
        reference_given: the file names its ``reference`` (then it must be one of the file's
            agents, checked where they are resolved); without it the reference is
            ``incremental_ik``, and a suite that does not play it has no paired comparison.
        truth_twins: every agent that observes the estimate (not privileged, not fed pixels,
            not ``random`` or ``hold``, which never read the target) also plays each ranked
            analytic scenario's truth-fed twin (``<X>_truth``,
            `capture_bench.task.scenarios.truth_twin`) on the same seeds; not ranked.
        rendered_twins: rendered scenarios (``<X>_rendered``, X one of ``scenarios``) that
            ``rendered_agents`` (some of ``agents``) play on the first ``rendered_episodes``
            seeds; not ranked. Empty: none.
    """

    name: str
    description: str
    agents: tuple[str, ...]
    scenarios: tuple[str, ...]
    episodes: int
    reference: str
    path: Path
    sha256: str
    videos: bool = True
    reference_given: bool = False
    truth_twins: bool = False
    rendered_twins: tuple[str, ...] = ()
    rendered_agents: tuple[str, ...] = ()
    rendered_episodes: int = 0


#: The seeds an evaluation can play (``EvaluationConfig.seed_set``).
SEED_SETS = ("evaluation", "validation")
VALIDATION_SUFFIX = "-validation"  # the report folder of a run on the validation seeds
VALIDATION_NOTE = (
    "Played on the scenarios' validation seeds, the seeds that training, tuning and model "
    "selection use, not on the published evaluation seeds: for choosing and comparing models, "
    "not a leaderboard."
)
_SCHEMA = {  # capture_bench.validation rules
    "description": Rule("string"),
    "agents": Rule("names"),
    "scenarios": Rule("names", choices=(ALL,)),
    "episodes": Rule("int", 1),
    "reference": Rule("string"),
    "videos": Rule("bool"),
    "truth_twins": Rule("bool"),
    "rendered_twins": Rule("names"),
    "rendered_agents": Rule("names"),
    "rendered_episodes": Rule("int", 1),
}


def list_suites(suites_dir: Path = SUITES_DIR) -> list[str]:
    """Names of the shipped suites, sorted."""
    return sorted(p.stem for p in suites_dir.glob("*.yaml"))


def shadowed_suite(name_or_path: str | Path, suites_dir: Path = SUITES_DIR) -> str | None:
    """The shipped suite a suite file would pass for: its name when ``name_or_path`` is a YAML
    path whose stem names a shipped suite but which is another file (``my/default.yaml``);
    None for a name, for the shipped file itself by any path, or for a stem no shipped suite
    has."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml") or path.stem not in list_suites(suites_dir):
        return None
    shipped = suites_dir / f"{path.stem}.yaml"
    return None if path.resolve() == shipped.resolve() else path.stem


def load_suite(name_or_path: str | Path, suites_dir: Path = SUITES_DIR) -> Suite:
    """Load and validate a shipped suite by name, or any suite YAML by path (named
    ``custom-<hash of the file>`` where `shadowed_suite` says it would pass for a shipped
    suite)."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = suites_dir / f"{name_or_path}.yaml"
        if not is_file(path):
            valid = ", ".join(list_suites(suites_dir)) or "none"
            raise SuiteError(f"unknown suite {str(name_or_path)!r}; valid suites: {valid}")
    if not is_file(path):
        raise SuiteError(f"{path}: no such suite file")
    data, raw = read_mapping(path, f"suite keys ({', '.join(_SCHEMA)})", SuiteError)
    required = {key: _SCHEMA[key].describe() for key in ("agents", "scenarios", "episodes")}
    checked = check_mapping(data, _SCHEMA, str(path), error=SuiteError, required=required)
    _check_rendered_keys(checked, path)
    sha256 = hashlib.sha256(raw).hexdigest()
    name, description = path.stem, checked.get("description", "")
    shadowed = shadowed_suite(path, suites_dir)
    if shadowed is not None:
        digest = hashlib.sha256(json.dumps(["suite file", shadowed, sha256]).encode()).hexdigest()
        name = f"custom-{digest[:8]}"
        description = f"suite file {path}, not the shipped {shadowed!r} suite: {description}"
    return Suite(
        name=name,
        description=description,
        agents=checked["agents"],
        scenarios=checked["scenarios"],
        episodes=checked["episodes"],
        reference=checked.get("reference", "incremental_ik"),
        path=path,
        sha256=sha256,
        videos=checked.get("videos", True),
        reference_given="reference" in checked,
        truth_twins=checked.get("truth_twins", False),
        rendered_twins=checked.get("rendered_twins", ()),
        rendered_agents=checked.get("rendered_agents", ()),
        rendered_episodes=min(checked.get("rendered_episodes", 0), checked["episodes"]),
    )


def _check_rendered_keys(checked: dict[str, Any], path: Path) -> None:
    """``rendered_twins``, ``rendered_agents`` and ``rendered_episodes`` come together;
    `SuiteError` naming the keys missing otherwise."""
    keys = ("rendered_twins", "rendered_agents", "rendered_episodes")
    given = [key for key in keys if key in checked]
    if given and len(given) < len(keys):
        missing = ", ".join(k for k in keys if k not in given)
        raise SuiteError(
            f"{path}: key {given[0]!r} needs {missing} too: the rendered scenarios, the agents "
            "that play them and on how many seeds; give all three or none"
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
        changes["rendered_episodes"] = min(suite.rendered_episodes, episodes)
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
