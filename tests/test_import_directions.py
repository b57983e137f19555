"""Imports point one way: down the data flow, never back up and never in a circle.

Every module under ``capture_bench/`` is parsed with `ast` (nothing is imported), and every
import of a ``capture_bench`` module is read: at module level, inside functions, under
``TYPE_CHECKING`` (a type is a dependency too), relative ones, and ``importlib.import_module`` /
``__import__`` / ``"module:Name"`` entry points given as literal strings. An import of a name from
a module is an arrow to that module; ``from package import submodule`` is an arrow to the
submodule. Importing a submodule also runs its package's ``__init__.py``, but that is Python's
doing, not the importing module's, so it is no arrow here.

Stages, lowest first (`STAGES`): the helpers any stage may use (top-level modules such as
``paths.py``), ``sim``, ``sensing``, ``task``, ``engine``, ``envs``, the package's
``__init__.py`` (importing ``capture_bench`` registers the environments' IDs), ``agents``, then
``training`` and ``evaluation``, siblings that do not import each other, ``datasets`` (it
resolves and plays agents as evaluation does), and ``__main__.py`` above all. A module may import its own stage and the stages below it. Anything that has to break this
is listed in `EXCEPTIONS` with its reason.

Within ``training``, each job has its folder (`TRAINING_JOBS`: ``train``, ``tune``, ``sweep``,
``curves``, ``zoo``) over what they share (``config``, ``common`` and the top-level modules): a
job's modules are imported only by the same job, never by another job nor by what they share.
Within ``evaluation``, ``running`` (suites, agents, rollouts, backends, videos) never imports
``reporting`` (what the report makes of the records).
"""

from __future__ import annotations

import ast
import functools
import re
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "capture_bench"

#: Sub-package or top-level module (the first name under ``capture_bench``) -> (stage, level).
#: A module may import modules of its own stage and of any lower level; two stages at one level
#: (training and evaluation) may not import each other.
STAGES: dict[str, tuple[str, int]] = {
    **{
        name: ("helpers", 0)
        for name in (
            "paths",
            "files",
            "validation",
            "provenance",
            "argparsing",
            "interrupts",
            "_quiet",
            "progress",
            "rliable_stats",
            "ray_cluster",
            "worker_processes",
        )
    },
    "sim": ("sim", 1),
    "sensing": ("sensing", 2),
    "task": ("task", 3),
    "engine": ("engine", 4),
    "envs": ("envs", 5),
    "__init__": ("registration", 6),  # `import capture_bench` registers the envs' IDs
    "agents": ("agents", 7),
    "training": ("training", 8),
    "evaluation": ("evaluation", 8),
    "datasets": ("datasets", 9),  # records agents' episodes: resolves them as evaluation does
    "__main__": ("command", 10),  # python -m capture_bench evaluate | train | tune | list
}

#: (importing module, imported module) -> why this arrow must stay although it breaks the rule.
EXCEPTIONS: dict[tuple[str, str], str] = {}

#: Modules that exist only for a name pickled in shipped files, so no module may import them.
PICKLED_PATHS: dict[str, str] = {
    "capture_bench.training.features": (
        "the SB3 .zip files under models/ pickle the features extractor under this path; the class "
        "lives in capture_bench.agents.features"
    ),
}

#: The folders of ``capture_bench.training`` that hold one job each; none imports another.
TRAINING_JOBS = ("train", "tune", "sweep", "curves", "zoo")

_ENTRY_POINT = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_]\w*")


@dataclass(frozen=True)
class Arrow:
    """One import: ``source`` imports ``target`` at ``path:line`` (``text`` as written)."""

    source: str
    target: str
    path: str
    line: int
    text: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.source} -> {self.target}  ({self.text})"


def module_files(root: Path, package: str = PACKAGE) -> dict[str, Path]:
    """Module name -> file, for every ``.py`` file of ``package`` under ``root``."""
    modules = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The module that ``name`` (a module, or a module's attribute) names: its longest prefix
    that is a module of the package; None outside the package."""
    parts = name.split(".")
    for end in range(len(parts), 0, -1):
        candidate = ".".join(parts[:end])
        if candidate in modules:
            return candidate
    return None


def _imported_names(node: ast.AST, module: str, is_package: bool) -> list[str]:
    """The dotted names that ``node`` imports (empty if it imports nothing)."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom):
        if node.level:
            base = module.split(".")
            if not is_package:
                base = base[:-1]
            base = base[: len(base) - (node.level - 1)]
            prefix = ".".join([*base, *([node.module] if node.module else [])])
        else:
            prefix = node.module or ""
        return [prefix] + [f"{prefix}.{alias.name}" for alias in node.names]
    if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
        func = node.func
        called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
        if called in ("import_module", "__import__") and isinstance(node.args[0].value, str):
            return [node.args[0].value]
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        if _ENTRY_POINT.fullmatch(node.value):
            return [node.value.partition(":")[0]]
    return []


def find_arrows(root: Path, package: str = PACKAGE) -> tuple[dict[str, Path], list[Arrow]]:
    """Every module of ``package`` and every import from one of them to another."""
    modules = module_files(root, package)
    arrows = []
    for module, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        is_package = path.name == "__init__.py"
        for node in ast.walk(tree):
            names = _imported_names(node, module, is_package)
            if not names:
                continue
            if isinstance(node, ast.ImportFrom):  # from X import a: X.a if a module, else X
                prefix, *members = names
                targets = {m if m in modules else _resolve(prefix, modules) for m in members}
            else:
                targets = {_resolve(name, modules) for name in names}
            for target in sorted(t for t in targets if t is not None and t != module):
                text = ast.unparse(node) if not isinstance(node, ast.Constant) else repr(node.value)
                arrows.append(Arrow(module, target, str(path.relative_to(root)), node.lineno, text))
    return modules, arrows


def stage_of(module: str) -> tuple[str, int] | None:
    """The (stage, level) of ``module``, from the first name under the package."""
    parts = module.split(".")
    return STAGES.get(parts[1] if len(parts) > 1 else "__init__")


def back_arrows(arrows: list[Arrow]) -> list[Arrow]:
    """The arrows from a module to a stage that is neither its own nor lower, not excepted."""
    wrong = []
    for arrow in arrows:
        source, target = stage_of(arrow.source), stage_of(arrow.target)
        if source is None or target is None:
            continue  # test_every_module_has_a_stage names them
        if target[0] != source[0] and target[1] >= source[1]:
            if (arrow.source, arrow.target) not in EXCEPTIONS:
                wrong.append(arrow)
    return wrong


def training_job(module: str) -> str | None:
    """The training job whose folder holds ``module`` (`TRAINING_JOBS`), or None."""
    parts = module.split(".")
    if parts[1:2] == ["training"] and len(parts) > 2 and parts[2] in TRAINING_JOBS:
        return parts[2]
    return None


def job_crossings(arrows: list[Arrow]) -> list[Arrow]:
    """The arrows from a module of ``training`` into a job's folder other than its own: from
    another job, or from what the jobs share (``config``, ``common``, the top-level modules)."""
    return [
        arrow
        for arrow in arrows
        if arrow.source.split(".")[1:2] == ["training"]
        and training_job(arrow.target) is not None
        and training_job(arrow.source) != training_job(arrow.target)
    ]


def running_into_reporting(arrows: list[Arrow]) -> list[Arrow]:
    """The arrows from ``evaluation.running`` into ``evaluation.reporting``."""
    running, reporting = f"{PACKAGE}.evaluation.running", f"{PACKAGE}.evaluation.reporting"
    return [
        arrow
        for arrow in arrows
        if (arrow.source == running or arrow.source.startswith(running + "."))
        and (arrow.target == reporting or arrow.target.startswith(reporting + "."))
    ]


def cycles(arrows: list[Arrow]) -> list[tuple[list[str], list[Arrow]]]:
    """Each group of modules that import each other in a loop (Tarjan's strongly connected
    components), with one circle of arrows through it: a shortest way from its first module back."""
    graph: dict[str, dict[str, Arrow]] = {}
    for arrow in arrows:
        graph.setdefault(arrow.source, {}).setdefault(arrow.target, arrow)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []

    def visit(node: str) -> None:  # recursion depth <= number of modules (~100)
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph.get(node, {}):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = set()
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.add(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(component)

    for node in sorted(graph):
        if node not in index:
            visit(node)
    circles = []
    for component in components:  # a shortest way from its first module back to itself
        start = min(component)
        parents: dict[str, str] = {}
        queue, last = deque([start]), None
        while last is None:
            node = queue.popleft()
            for nxt in sorted(graph[node]):
                if nxt == start:
                    last = node
                    break
                if nxt in component and nxt not in parents:
                    parents[nxt] = node
                    queue.append(nxt)
        way = [last]
        while way[-1] != start:
            way.append(parents[way[-1]])
        way = [*reversed(way), start]
        circles.append((sorted(component), [graph[a][b] for a, b in zip(way, way[1:])]))
    return circles


@functools.cache
def _package() -> tuple[dict[str, Path], list[Arrow]]:
    return find_arrows(ROOT)


def test_every_module_has_a_stage() -> None:
    modules, _ = _package()
    missing = [m for m in modules if stage_of(m) is None]
    assert not missing, f"modules of no stage (add them to STAGES): {missing}"


def test_no_import_runs_back_up() -> None:
    _, arrows = _package()
    wrong = back_arrows(arrows)
    lines = [f"{a}  [{stage_of(a.source)[0]} -> {stage_of(a.target)[0]}]" for a in wrong]
    assert not wrong, "imports toward a stage that is not below:\n" + "\n".join(lines)


def test_no_import_cycle() -> None:
    _, arrows = _package()
    found = cycles(arrows)
    text = "\n\n".join(
        f"{', '.join(group)}, for one:\n" + "\n".join(str(a) for a in circle)
        for group, circle in found
    )
    assert not found, f"modules that import each other in a circle:\n{text}"


def test_training_jobs_never_import_each_other() -> None:
    _, arrows = _package()
    wrong = job_crossings(arrows)
    assert not wrong, "imports into another training job's folder (move what is shared to " + (
        "training/common/):\n" + "\n".join(str(a) for a in wrong)
    )


def test_evaluation_running_never_imports_reporting() -> None:
    _, arrows = _package()
    wrong = running_into_reporting(arrows)
    assert not wrong, "evaluation.running imports evaluation.reporting:\n" + "\n".join(
        str(a) for a in wrong
    )


def test_exceptions_are_still_needed() -> None:
    _, arrows = _package()
    present = {(a.source, a.target) for a in arrows}
    stale = [pair for pair in EXCEPTIONS if pair not in present]
    assert not stale, f"EXCEPTIONS that no import needs any more: {stale}"


def test_pickled_paths_exist_and_nothing_imports_them() -> None:
    modules, arrows = _package()
    assert set(PICKLED_PATHS) <= set(modules)
    importers = [str(a) for a in arrows if a.target in PICKLED_PATHS]
    assert not importers, "import the class where it lives, not its pickled path:\n" + "\n".join(
        importers
    )


@pytest.fixture
def tangled(tmp_path: Path) -> Path:
    """A small package with one back-arrow in a function and a circle of relative imports."""
    files = {
        "__init__.py": "",
        "paths.py": "",
        "sim/__init__.py": "",
        "sim/world.py": "def f():\n    from capture_bench.envs import core\n",
        "envs/__init__.py": "",
        "envs/core.py": "from . import step\nfrom .. import paths\n",
        "envs/step.py": "from .core import thing\n",
        "agents/__init__.py": "import importlib\nimportlib.import_module('capture_bench.paths')\n",
    }
    for name, text in files.items():
        (tmp_path / PACKAGE / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / PACKAGE / name).write_text(text)
    return tmp_path


def test_the_checks_find_a_back_arrow_and_a_circle(tangled: Path) -> None:
    _, arrows = find_arrows(tangled)
    pairs = {(a.source, a.target) for a in arrows}
    assert pairs == {
        ("capture_bench.sim.world", "capture_bench.envs.core"),
        ("capture_bench.envs.core", "capture_bench.envs.step"),
        ("capture_bench.envs.core", "capture_bench.paths"),
        ("capture_bench.envs.step", "capture_bench.envs.core"),
        ("capture_bench.agents", "capture_bench.paths"),
    }
    [wrong] = back_arrows(arrows)
    assert str(wrong).startswith("capture_bench/sim/world.py:2: capture_bench.sim.world -> ")
    [(group, circle)] = cycles(arrows)
    assert group == ["capture_bench.envs.core", "capture_bench.envs.step"]
    assert sorted((a.source, a.target) for a in circle) == [
        ("capture_bench.envs.core", "capture_bench.envs.step"),
        ("capture_bench.envs.step", "capture_bench.envs.core"),
    ]


def test_the_job_check_finds_a_job_importing_another(tmp_path: Path) -> None:
    files = {
        "__init__.py": "",
        "training/__init__.py": "",
        "training/callbacks.py": "",
        "training/common/__init__.py": "",
        "training/common/build.py": "from capture_bench.training import callbacks\n",
        "training/common/plan.py": "from capture_bench.training.sweep import task\n",
        "training/tune/__init__.py": "",
        "training/tune/command.py": (
            "from capture_bench.training.common import build\nfrom . import trial\n"
            "def f():\n    from capture_bench.training.train.command import main\n"
        ),
        "training/tune/trial.py": "",
        "training/train/__init__.py": "",
        "training/train/command.py": "main = None\n",
        "training/sweep/__init__.py": "",
        "training/sweep/task.py": "",
    }
    for name, text in files.items():
        (tmp_path / PACKAGE / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / PACKAGE / name).write_text(text)
    _, arrows = find_arrows(tmp_path)
    assert sorted((a.source, a.target) for a in job_crossings(arrows)) == [
        ("capture_bench.training.common.plan", "capture_bench.training.sweep.task"),
        ("capture_bench.training.tune.command", "capture_bench.training.train.command"),
    ]


def test_the_evaluation_check_finds_running_importing_reporting(tmp_path: Path) -> None:
    files = {
        "__init__.py": "",
        "evaluation/__init__.py": "",
        "evaluation/errors.py": "",
        "evaluation/pipeline.py": "from .reporting import report\nfrom .running import backends\n",
        "evaluation/running/__init__.py": "",
        "evaluation/running/backends.py": "from capture_bench.evaluation import errors\n",
        "evaluation/running/video.py": "def f():\n    from ..reporting.plots import draw\n",
        "evaluation/reporting/__init__.py": "",
        "evaluation/reporting/report.py": "from capture_bench.evaluation.running import backends\n",
        "evaluation/reporting/plots.py": "",
    }
    for name, text in files.items():
        (tmp_path / PACKAGE / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / PACKAGE / name).write_text(text)
    _, arrows = find_arrows(tmp_path)
    assert [(a.source, a.target) for a in running_into_reporting(arrows)] == [
        ("capture_bench.evaluation.running.video", "capture_bench.evaluation.reporting.plots"),
    ]
