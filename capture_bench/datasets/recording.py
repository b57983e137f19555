"""A recording: its plan (`RecordingPlan`: scenario, agents, seeds), its staging folder, and the
Minari dataset it writes (`record`).

Resuming: every finished episode is written at once to the staging folder,
``<root>/.capture-bench-staging/<dataset id, / as __>/``, as ``<seed>-<agent index>.npz``
(`capture_bench.datasets.episodes.save_episode`: whole or absent), beside the plan
(``plan.json``). A recording interrupted (Ctrl-C, SIGTERM, a crash) keeps its finished episodes
there; ``--resume`` checks that the plan is the same and plays only the episodes whose file is
missing, so no episode is played twice or stored twice. When every episode is staged, the
dataset is written into the staging folder and renamed onto ``<root>/<dataset id>/data``, then
the staging folder is removed: a dataset folder is always a whole dataset. The staging folder's
name starts with a dot, so Minari's ``list_local_datasets`` does not list it.

``<root>`` is Minari's datasets folder: ``MINARI_DATASETS_PATH`` if set, else
``~/.minari/datasets``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from capture_bench.datasets.episodes import load_episode, play_episode, save_episode, to_buffer
from capture_bench.evaluation.errors import EvaluationError
from capture_bench.task.scenarios import Scenario

STAGING_DIR = ".capture-bench-staging"
PLAN_FILE = "plan.json"
SEED_SETS = ("training", "validation", "evaluation")
#: What a dataset says about replaying it (its metadata's ``capture_bench.reproducibility``).
REPRODUCIBILITY = (
    "reset the env recovered from this dataset with an episode's seed and step its actions: "
    "the same observations, rewards, terminations and info, bit for bit, on the capture-bench "
    "version (package version and git commit) recorded here; another version may differ"
)


class DatasetError(EvaluationError):
    """Bad dataset input (agent, scenario, seeds, dataset id, resume); the message says what is
    valid."""


def minari_root() -> Path:
    """Minari's datasets folder: ``MINARI_DATASETS_PATH``, else ``~/.minari/datasets``."""
    root = os.environ.get("MINARI_DATASETS_PATH")
    return Path(root) if root else Path.home() / ".minari" / "datasets"


def default_dataset_id(scenario: str, labels: Sequence[str]) -> str:
    """``capture-bench/<scenario>/<agents>-v0``, the agents' labels joined by ``-``, each made
    of letters, digits, ``_`` and ``-`` only (Minari's rule for a dataset name)."""
    names = "-".join(re.sub(r"[^\w-]+", "_", label) for label in labels)
    return f"capture-bench/{scenario}/{names}-v0"


def check_dataset_id(dataset_id: str) -> str:
    """``dataset_id`` if it is ``(namespace/)name-v<version>`` of letters, digits, ``_`` and
    ``-`` (Minari's rule, a version required), else `DatasetError`."""
    from minari.dataset.minari_dataset import parse_dataset_id

    valid = (
        "valid: (namespace/)name-v<version> of letters, digits, _ and -, e.g. "
        "capture-bench/paper/planned_intercept-v0"
    )
    if not re.fullmatch(r"[\w-]+(/[\w-]+)*", dataset_id):
        raise DatasetError(f"--id {dataset_id!r} is not a Minari dataset id; {valid}")
    if not re.search(r"-v\d+$", dataset_id):
        raise DatasetError(f"--id {dataset_id!r} has no version (-v<N>); {valid}")
    try:
        parse_dataset_id(dataset_id)
    except (TypeError, ValueError):
        raise DatasetError(f"--id {dataset_id!r} is not a Minari dataset id; {valid}") from None
    return dataset_id


def seed_range(scenario: Scenario, seed_set: str, first: int | None, count: int) -> range:
    """The seeds ``first`` .. ``first + count - 1`` (``first``: the set's first seed when None),
    all within ``seed_set`` (``training`` or ``validation``) of ``scenario``. A published
    evaluation seed, or a seed outside the set, is a `DatasetError`."""
    published = range(
        scenario.seeds.evaluation_start,
        scenario.seeds.evaluation_start + scenario.seeds.evaluation_count,
    )
    sets = {"training": scenario.training_seeds, "validation": scenario.validation_seeds}
    valid = (
        f"training seeds {_span(sets['training'])} or validation seeds {_span(sets['validation'])}"
    )
    if seed_set == "evaluation":
        raise DatasetError(
            f"the published evaluation seeds of {scenario.name} ({_span(published)}) are "
            f"reserved for the leaderboard; record {valid}"
        )
    allowed = sets[seed_set]
    start = allowed.start if first is None else first
    seeds = range(start, start + count)
    for seed in (seeds[0], seeds[-1]) if seeds else ():
        if seed in published or (seeds.start < published.start < seeds.stop):
            hit = seed if seed in published else published.start
            raise DatasetError(
                f"seed {hit} is a published evaluation seed of {scenario.name} "
                f"({_span(published)}), reserved for the leaderboard; record {valid}"
            )
        if seed not in allowed:
            raise DatasetError(
                f"seed {seed} is not one of {scenario.name}'s {seed_set} seeds "
                f"({_span(allowed)}); choose --first-seed and --episodes within them"
            )
    return seeds


def _span(seeds: range) -> str:
    return f"{seeds.start}-{seeds.stop - 1}"


@dataclass(frozen=True)
class RecordingPlan:
    """What a recording plays: every agent on every seed (seed after seed, the agents in order
    for each), on ``scenario``'s env ``env_id``.

    Attributes:
        dataset_id: the Minari dataset id.
        scenario: the scenario's name.
        env_id: its registered env id.
        agents: the agent specs as given.
        labels: their labels (the episode metadata's ``agent``).
        seed_set: ``training`` or ``validation``.
        first_seed: the first seed.
        episodes: seeds per agent.
        privileged: the rows hold the true target state.
    """

    dataset_id: str
    scenario: str
    env_id: str
    agents: tuple[str, ...]
    labels: tuple[str, ...]
    seed_set: str
    first_seed: int
    episodes: int
    privileged: bool

    @property
    def seeds(self) -> range:
        """The seeds, in order."""
        return range(self.first_seed, self.first_seed + self.episodes)

    def order(self) -> list[tuple[int, int]]:
        """Every episode as (seed, agent index), in the dataset's order."""
        return [(seed, a) for seed in self.seeds for a in range(len(self.agents))]

    def to_json(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


def staging_dir(root: Path, dataset_id: str) -> Path:
    """Where ``dataset_id``'s unfinished recording keeps its episodes."""
    return root / STAGING_DIR / dataset_id.replace("/", "__")


def episode_file(staging: Path, seed: int, agent: int) -> Path:
    return staging / f"{seed}-{agent}.npz"


def prepare_staging(plan: RecordingPlan, root: Path, resume: bool) -> Path:
    """The staging folder of ``plan``, created, or found again with ``resume``. `DatasetError`:
    the dataset exists; an unfinished recording exists and ``resume`` is not given; it was of
    another plan."""
    final = root / plan.dataset_id / "data"
    if final.exists():
        raise DatasetError(
            f"dataset {plan.dataset_id} already exists ({final.parent}); choose another --id "
            f"(a new version, -v<N>) or delete it (minari delete {plan.dataset_id})"
        )
    staging = staging_dir(root, plan.dataset_id)
    plan_file = staging / PLAN_FILE
    if plan_file.is_file():
        if not resume:
            raise DatasetError(
                f"an interrupted recording of {plan.dataset_id} is in {staging} "
                f"({len(staged(staging))} episodes); add --resume to continue it, or delete "
                "that folder to start again"
            )
        _check_same_plan(json.loads(plan_file.read_text()), plan.to_json(), staging)
        return staging
    staging.mkdir(parents=True, exist_ok=True)
    from capture_bench.files import atomic_write

    atomic_write(plan_file, (json.dumps(plan.to_json(), indent=2) + "\n").encode())
    return staging


def _check_same_plan(old: dict[str, Any], new: dict[str, Any], staging: Path) -> None:
    for key, value in new.items():
        if old.get(key) != value:
            raise DatasetError(
                f"--resume: the interrupted recording in {staging} has {key} "
                f"{old.get(key)!r}, this command {value!r}; give the same options, or another --id"
            )


def staged(staging: Path) -> set[tuple[int, int]]:
    """The (seed, agent index) of every episode staged in ``staging``."""
    found = set()
    for path in staging.glob("*.npz"):
        match = re.fullmatch(r"(-?\d+)-(\d+)\.npz", path.name)
        if match:
            found.add((int(match[1]), int(match[2])))
    return found


def record(
    plan: RecordingPlan,
    root: Path,
    staging: Path,
    *,
    make_env: Callable[[], Any],
    make_agent: Callable[[int, Any, int], Any],
    metadata: dict[str, Any],
    advance: Callable[[int], None] = lambda n: None,
) -> Path:
    """Play every episode of ``plan`` not yet staged, then write the dataset; return its folder.

    Args:
        plan: what to record.
        root: Minari's datasets folder.
        staging: the plan's staging folder (`prepare_staging`).
        make_env: the env (``gymnasium.make(plan.env_id)``).
        make_agent: (agent index, env, seed) -> a fresh agent for one episode.
        metadata: the dataset's metadata beyond Minari's own (provenance, description).
        advance: told of every episode staged, those found at the start included.
    """
    done = staged(staging)
    advance(len(done & set(plan.order())))
    todo = [e for e in plan.order() if e not in done]
    if todo:
        env = make_env()
        try:
            for seed, a in todo:
                episode = play_episode(
                    env,
                    make_agent(a, env, seed),
                    label=plan.labels[a],
                    seed=seed,
                    privileged=plan.privileged,
                )
                save_episode(episode_file(staging, seed, a), episode)
                advance(1)
        finally:
            env.close()
    return write_dataset(plan, root, staging, make_env, metadata)


def write_dataset(
    plan: RecordingPlan,
    root: Path,
    staging: Path,
    make_env: Callable[[], Any],
    metadata: dict[str, Any],
) -> Path:
    """Write the staged episodes, in the plan's order, as the Minari dataset (module docstring:
    where, and how it is made whole); return its folder."""
    import minari
    from minari.dataset.minari_storage import MinariStorage
    from minari.namespace import create_namespace, list_local_namespaces

    env = make_env()
    try:
        spaces = (env.observation_space, env.action_space, env.spec)
    finally:
        env.close()
    data = staging / "data"
    if data.exists():  # a write interrupted before its rename: start it again
        shutil.rmtree(data)
    storage = MinariStorage.new(data, spaces[0], spaces[1], env_spec=spaces[2], data_format="hdf5")
    episodes = [load_episode(episode_file(staging, s, a)) for s, a in plan.order()]
    storage.update_episodes(to_buffer(e, i) for i, e in enumerate(episodes))
    storage.update_episode_metadata([e.metadata() for e in episodes])
    storage.update_metadata(
        {"dataset_id": plan.dataset_id, "minari_version": minari.__version__, **metadata}
    )
    namespace = plan.dataset_id.rsplit("/", 1)[0] if "/" in plan.dataset_id else None
    if namespace is not None and namespace not in list_local_namespaces():
        create_namespace(namespace)
    final = root / plan.dataset_id
    final.mkdir(parents=True, exist_ok=True)
    os.replace(data, final / "data")
    shutil.rmtree(staging)
    return final
