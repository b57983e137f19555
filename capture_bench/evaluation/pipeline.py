"""Plan an evaluation (validate every input at the edge), run it, write the report.

`plan_evaluation` resolves the suite, scenarios, seeds and agents and raises one of
`INPUT_ERRORS` on bad input before any episode runs or any file is written;
`run_evaluation` runs the episodes on the chosen backend and writes ``<out>/<suite>/``.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from capture_bench import rliable_stats
from capture_bench.agents.sb3_policy import PolicyLoadError, read_metadata
from capture_bench.evaluation.errors import AgentSpecError, EvaluationError, SuiteError
from capture_bench.evaluation.reporting import reproduction
from capture_bench.evaluation.reporting import training_seeds as seed_report
from capture_bench.evaluation.reporting.aggregate import (
    RankingRow,
    Summary,
    rank_agents,
    summarise_cells,
    summary_cells,
)
from capture_bench.evaluation.reporting.report import (
    ReportData,
    figure_groups,
    figures,
    write_report,
)
from capture_bench.evaluation.reporting.reproduction import is_inside
from capture_bench.evaluation.reporting.vision import RENDERED_SUFFIX, rendered_twins
from capture_bench.evaluation.reporting.watch import choose_episodes
from capture_bench.evaluation.running.agents_loading import (
    BLIND_BUILTINS,
    AgentSpec,
    TrainingSeeds,
    check_agent,
    expand_specs,
    resolve_agent,
    training_seeds,
)
from capture_bench.evaluation.running.backends import (
    BACKENDS,
    RAY_BACKEND,
    EpisodeTask,
    close_envs,
    make_env,
    map_processes,
    run_task,
    run_tasks,
    scenario_label,
)
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.evaluation.running.suites import (
    ALL,
    SEED_SETS,
    SUITES_DIR,
    VALIDATION_NOTE,
    VALIDATION_SUFFIX,
    Suite,
    load_suite,
    narrow,
)
from capture_bench.evaluation.running.video import EpisodeVideo, record_video, write_videos
from capture_bench.files import check_writable, episode_file_name
from capture_bench.provenance import (
    display_path,
    file_sha256,
    git_state,
    machine,
    package_versions,
)
from capture_bench.ray_cluster import check_ray_cluster
from capture_bench.task.scenarios import (
    SCENARIO_DIR,
    TRUTH_SUFFIX,
    ConfigError,
    list_scenarios,
    load_scenario,
    truth_twin_base,
)
from capture_bench.validation import shown

#: Exceptions that mean "bad input": the CLI prints their message and exits with code 2. OSError:
#: a named path that cannot even be looked at ("File name too long", "Permission denied").
INPUT_ERRORS: tuple[type[Exception], ...] = (EvaluationError, ConfigError, PolicyLoadError, OSError)
VideoKey = tuple[str, str, int]  # (agent, scenario, seed)


@dataclass(frozen=True)
class EvaluationConfig:
    """What to evaluate and where (the CLI's options, typed).

    Attributes:
        suite: suite name (``configs/suites/<name>.yaml``) or path to a suite YAML.
        agents: agent specs replacing the suite's (None: the suite's).
        scenarios: scenario names replacing the suite's (None: the suite's).
        episodes: episodes per agent x scenario replacing the suite's (the first N seeds of
            ``seed_set``).
        seed_set: ``evaluation``: the scenarios' published evaluation seeds (the leaderboard);
            ``validation``: their validation seeds, to select and compare models without
            touching a published seed (the report goes to ``<out>/<suite>-validation/``).
        backend: ``serial``, ``process`` or ``ray``; None: ``process`` if more than one worker,
            else ``serial``.
        workers: local worker processes of the ``process`` backend; None: every usable CPU.
        ray_address: Ray cluster address (``ray`` backend); None for a local instance.
        out: reports are written to ``<out>/<suite>/``.
        episode_plots: if set, per-episode figures of the first seed of every agent x scenario.
        video: if set, animated GIFs of the first ``video_episodes`` seeds of every agent x
            scenario are written there (`capture_bench.evaluation.running.video`).
        video_episodes: how many seeds of each agent x scenario ``video`` records (>= 1, at most
            the episodes evaluated).
        trust_model: load a model directory that has no safe policy file from its SB3 ``.zip``
            (pickles, which can run code): only for models whose source you trust.
        publish: write the published report, ``reports/published/<suite>/``
            (`published_dir`): only a shipped
            suite as defined, on the published evaluation seeds, with ``out`` that folder.
            Without it, no output (``out``, ``episode_plots``, ``video``) may lie there.
    """

    suite: str = "default"
    agents: list[str] | None = None
    scenarios: list[str] | None = None
    episodes: int | None = None
    seed_set: str = "evaluation"
    backend: str | None = None
    workers: int | None = None
    ray_address: str | None = None
    out: Path = Path("reports")
    episode_plots: Path | None = None
    video: Path | None = None
    video_episodes: int = 1
    trust_model: bool = False
    publish: bool = False

    def resolved_workers(self) -> int:
        """Worker processes: as given, or every CPU this process may use."""
        if self.workers is None:
            return usable_cpus()
        if self.workers < 1:
            raise EvaluationError(f"--workers {self.workers}: expected a whole number >= 1")
        return self.workers

    def resolved_backend(self) -> str:
        """The backend that will run: as given, else ``process`` if more than one worker."""
        if self.backend is None:
            return "process" if self.resolved_workers() > 1 else "serial"
        if self.backend not in BACKENDS:
            raise EvaluationError(f"unknown backend {self.backend!r}; valid: {', '.join(BACKENDS)}")
        self.resolved_workers()
        return self.backend


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class Plan:
    """A validated evaluation: the suite as narrowed, agents, scenarios, seeds, tasks.

    ``tasks`` are the leaderboard's episodes; ``training_seeds`` (by agent label) the agents
    whose model was shipped from several training seeds, and ``seed_tasks`` the episodes of
    their other seeds' policies: the same scenarios and episode seeds as the agent's own.
    ``twin_tasks`` are the episodes on the scenarios' twins (`twin_tasks`), not ranked."""

    suite: Suite
    agents: list[AgentSpec]
    scenarios: list[str]
    seeds: dict[str, list[int]]
    tasks: list[EpisodeTask] = field(repr=False)
    config_hashes: dict[str, Any] = field(repr=False)
    seed_set: str = "evaluation"
    training_seeds: dict[str, TrainingSeeds] = field(default_factory=dict)
    seed_tasks: list[EpisodeTask] = field(default_factory=list, repr=False)
    twin_tasks: list[EpisodeTask] = field(default_factory=list, repr=False)

    @property
    def report_name(self) -> str:
        """The report's folder under ``--out``: the suite's name, and ``-validation`` after it
        on the validation seeds (so that report never replaces the leaderboard's)."""
        return report_folder_name(self.suite.name, self.seed_set)

    @property
    def description(self) -> str:
        """The suite's description, after a sentence naming the validation seeds where they
        are played."""
        if self.seed_set == "evaluation":
            return self.suite.description
        return f"{VALIDATION_NOTE} {self.suite.description}"


def report_folder_name(suite: str, seed_set: str) -> str:
    """The report's folder under ``--out``: the suite's name, and ``-validation`` after it on
    the validation seeds."""
    return suite + ("" if seed_set == "evaluation" else VALIDATION_SUFFIX)


def _scenario_names(suite: Suite) -> list[str]:
    if suite.scenarios == (ALL,):  # every valid analytic one; the CLI names invalid files skipped
        return list_scenarios(camera="analytic")
    known = list_scenarios()
    for name in suite.scenarios:
        if is_scenario_file(name):  # a scenario YAML by path, as train.py --scenario takes
            load_scenario(name)  # raises the file's error (file, key, what is valid)
            continue
        if name not in known:
            load_scenario(name)  # an invalid shipped file raises its own error (file, key, valid)
            raise EvaluationError(f"unknown scenario {name!r}; valid: {', '.join(known)}")
    return list(suite.scenarios)


def _model_provenance(spec: AgentSpec) -> dict[str, Any]:
    meta = read_metadata(spec.target)
    return {
        "directory": display_path(meta.directory),
        "algorithm": meta.algorithm,
        "trained_on": meta.scenario,
        "trained_observation_source": meta.observation_source,
        "loaded_from": "SB3 .zip (trusted)" if meta.weights_file is None else "safe policy file",
        "sha256": {p.name: file_sha256(p) for p in meta.files},
    }


def is_scenario_file(name: str) -> bool:
    """Whether a scenario spec is a YAML path rather than a shipped scenario's name."""
    return Path(name).suffix in (".yaml", ".yml")


def scenario_file(name: str) -> Path:
    """The YAML file a scenario spec names."""
    return Path(name) if is_scenario_file(name) else SCENARIO_DIR / f"{name}.yaml"


def plan_evaluation(config: EvaluationConfig) -> Plan:
    """Validate the whole request; raises one of `INPUT_ERRORS` naming what is wrong.

    The output folders are checked writable last, so bad input of any kind costs no episode and
    leaves no file."""
    if not rliable_stats.installed():  # the report's aggregate statistics
        raise EvaluationError(rliable_stats.MISSING)
    config.resolved_backend()
    loaded = load_suite(config.suite)
    suite = narrow(loaded, config.agents, config.scenarios, config.episodes)
    scenarios = _scenario_names(suite)
    labels = [scenario_label(name) for name in scenarios]
    clash = next((x for x in labels if labels.count(x) > 1), None)
    if clash:
        raise EvaluationError(
            f"two scenarios are both named {clash!r} in the report; give the file its own "
            "'name' key or file name"
        )
    if config.seed_set not in SEED_SETS:
        raise EvaluationError(
            f"--seed-set {config.seed_set!r}: expected one of {', '.join(SEED_SETS)}"
        )
    seeds: dict[str, list[int]] = {}
    for name in scenarios:
        scenario = load_scenario(name)
        available = list(
            scenario.evaluation_seeds
            if config.seed_set == "evaluation"
            else scenario.validation_seeds
        )
        if suite.episodes > len(available):
            raise EvaluationError(
                f"{suite.episodes} episodes requested but scenario {name!r} has "
                f"{len(available)} {config.seed_set} seeds; use --episodes <= {len(available)}"
            )
        seeds[name] = available[: suite.episodes]
    specs = [
        resolve_agent(s, trust_model=config.trust_model) for s in expand_specs(list(suite.agents))
    ]
    if not specs:
        raise AgentSpecError("no agent to evaluate (models/* matched no model directory)")
    labels = [s.label for s in specs]
    duplicate = next((x for x in labels if labels.count(x) > 1), None)
    if duplicate:
        raise AgentSpecError(f"two agent specs are both named {duplicate!r} in the report")
    _check_reference(loaded, suite, labels)
    _check_rendered_agents(loaded, suite, specs)
    seeded = {s.label: found for s in specs if (found := training_seeds(s)) is not None}
    seed_specs = {  # (agent label, training seed) -> that seed's policy
        (spec.label, seed): resolve_agent(path, trust_model=spec.trust_model)
        for spec in specs
        if spec.label in seeded
        for seed, path in seeded[spec.label].specs.items()
    }
    to_check = [s for s in specs if s.kind != "builtin"] + list(seed_specs.values())
    if to_check:
        for name in scenarios:
            envs: dict[str, Any] = {}  # each spec checked in the env it plays in
            try:
                for spec in to_check:
                    key = str(spec.env_options())
                    if key not in envs:
                        envs[key] = make_env(name, **spec.env_options())
                    check_agent(spec, envs[key], name)
            finally:
                for env in envs.values():
                    env.close()
    tasks = [
        EpisodeTask(spec.spec, name, seed, spec.trust_model)
        for spec in specs
        for name in scenarios
        for seed in seeds[name]
    ]
    seed_tasks = [
        EpisodeTask(spec.spec, name, seed, spec.trust_model)
        for spec in seed_specs.values()
        for name in scenarios
        for seed in seeds[name]
    ]
    twins = twin_tasks(suite, specs, scenarios, seeds)
    hashes: dict[str, Any] = {
        "suite": {"file": display_path(suite.path), "sha256": suite.sha256},
        "scenarios": {
            n: file_sha256(scenario_file(n))
            for n in dict.fromkeys([*scenarios, *(t.scenario for t in twins)])
            if truth_twin_base(n) is None  # a truth twin is its scenario's file, derived
        },
        "models": {s.label: _model_provenance(s) for s in specs if s.kind == "model"},
    }
    for (label, seed), spec in seed_specs.items():  # each training seed's policy files
        found = hashes["models"][label].setdefault("training_seeds", {})
        found[str(seed)] = _model_provenance(spec)["sha256"]
    if config.video is not None and not 1 <= config.video_episodes <= suite.episodes:
        raise EvaluationError(
            f"--video-episodes {config.video_episodes}: expected a whole number from 1 to the "
            f"{suite.episodes} episodes evaluated of each agent x scenario"
        )
    if config.resolved_backend() == "ray":
        check_ray_cluster(config.ray_address, RAY_BACKEND)
    _check_published_folder(config, suite, report_folder_name(suite.name, config.seed_set))
    check_writable(config.out, "--out")
    if config.episode_plots is not None:
        check_writable(config.episode_plots, "--episode-plots")
    if config.video is not None:
        check_writable(config.video, "--video")
    return Plan(
        suite, specs, scenarios, seeds, tasks, hashes, config.seed_set, seeded, seed_tasks, twins
    )


def observes_estimate(spec: AgentSpec) -> bool:
    """Whether the agent acts on the estimator's output: not privileged (the oracle reads the
    true state), not fed the camera's pixels, and not one of `BLIND_BUILTINS`."""
    blind = spec.kind == "builtin" and spec.target in BLIND_BUILTINS
    return not (spec.privileged or blind or "observation_source" in spec.env_options())


def twin_tasks(
    suite: Suite, specs: Sequence[AgentSpec], scenarios: Sequence[str], seeds: dict[str, list[int]]
) -> list[EpisodeTask]:
    """The episodes on the scenarios' twins, not ranked: with ``suite.truth_twins``, every
    agent that `observes_estimate` on each ranked shipped analytic scenario's truth-fed twin
    (``<X>_truth``), on the scenario's seeds; then `_rendered_tasks`. Raises `SuiteError` for
    a rendered twin that is none."""
    tasks = []
    if suite.truth_twins:
        for name in scenarios:
            scenario = load_scenario(name)
            if is_scenario_file(name) or not scenario.ranked or scenario.camera.mode != "analytic":
                continue
            tasks += [
                EpisodeTask(spec.spec, name + TRUTH_SUFFIX, seed, spec.trust_model)
                for spec in specs
                if observes_estimate(spec)
                for seed in seeds[name]
            ]
    return tasks + _rendered_tasks(suite, specs, scenarios, seeds)


def _rendered_tasks(
    suite: Suite, specs: Sequence[AgentSpec], scenarios: Sequence[str], seeds: dict[str, list[int]]
) -> list[EpisodeTask]:
    """``suite.rendered_agents`` on each of ``suite.rendered_twins`` whose analytic scenario is
    among ``scenarios`` (a narrowed suite drops the others), first ``rendered_episodes`` seeds."""
    tasks = []
    for twin in suite.rendered_twins:
        base = twin.removesuffix(RENDERED_SUFFIX)
        if not rendered_twins([base, twin]):
            raise SuiteError(
                f"{suite.path}: key 'rendered_twins': {shown(twin)} is not valid; expected "
                f"the rendered twin X{RENDERED_SUFFIX} (the same seeds) of a shipped "
                "scenario X with the analytic camera"
            )
        if base not in scenarios:
            continue
        tasks += [
            EpisodeTask(spec.spec, twin, seed, spec.trust_model)
            for spec in specs
            if spec.label in suite.rendered_agents or spec.spec in suite.rendered_agents
            for seed in seeds[base][: suite.rendered_episodes]
        ]
    return tasks


def _check_rendered_agents(loaded: Suite, suite: Suite, specs: Sequence[AgentSpec]) -> None:
    """``SuiteError`` if the suite file names a rendered agent that is none of its agents (as
    the file writes it, or its report name); with ``--agents`` the others are left out."""
    if suite.agents != loaded.agents:
        return
    known = [name for spec in specs for name in (spec.spec, spec.label)]
    for name in suite.rendered_agents:
        if name not in known:
            raise SuiteError(
                f"{loaded.path}: key 'rendered_agents': {shown(name)} is not valid; expected "
                f"one of the suite's agents: {', '.join(s.label for s in specs)}"
            )


def _check_published_folder(config: EvaluationConfig, suite: Suite, report_name: str) -> None:
    """Only ``--publish`` writes under the published folder, and it publishes only a shipped
    suite as defined on the published seeds; raises `EvaluationError` otherwise."""
    published = reproduction.published_dir()
    if not config.publish:
        for option, path in (
            ("--out", config.out),
            ("--out", Path(config.out) / report_name),  # the report's own folder
            ("--episode-plots", config.episode_plots),
            ("--video", config.video),
        ):
            if path is not None and is_inside(path, published):
                raise EvaluationError(
                    f"{option} {path}: {display_path(published)}/ holds the published "
                    "leaderboard, which only python evaluate.py --publish writes; choose a "
                    "folder outside it (the default, reports/, is git-ignored)"
                )
        return
    shipped = SUITES_DIR / f"{suite.name}.yaml"
    if (
        config.seed_set != "evaluation"
        or not shipped.is_file()
        or suite.sha256 != file_sha256(shipped)
    ):
        raise EvaluationError(
            f"--publish writes {display_path(published)}/<suite>/, the published leaderboard: "
            "only a shipped suite as defined, on the published evaluation seeds; drop --agents, "
            "--scenarios, --episodes and --seed-set, or drop --publish"
        )
    if Path(config.out).resolve() != published.resolve():
        raise EvaluationError(
            f"--publish writes {display_path(published)}/ and takes no --out ({config.out}); "
            "drop --out"
        )


def _check_reference(loaded: Suite, suite: Suite, labels: list[str]) -> None:
    """``SuiteError`` if the suite file names a ``reference`` that is none of its agents (their
    report names, ``labels``). Agents given on the command line (``--agents``) replace the
    file's: the reference is then compared with whichever of them it is, if any."""
    if loaded.reference_given and suite.agents == loaded.agents and suite.reference not in labels:
        raise SuiteError(
            f"{loaded.path}: key 'reference': {shown(suite.reference)} is not valid; expected "
            f"one of the suite's agents: {', '.join(labels)}"
        )


def _provenance(
    plan: Plan, config: EvaluationConfig, command: str, seconds: float, videos: dict[str, Any]
) -> dict:
    return {
        "command": command,
        "git": git_state(),
        "packages": package_versions(),
        "machine": machine(),
        "config_hashes": plan.config_hashes,
        "seed_set": plan.seed_set,
        "seeds": plan.seeds,
        "agents": [
            {
                "label": s.label,
                "spec": display_path(Path(s.target)) if s.kind == "model" else s.spec,
                "kind": s.kind,
                "privileged": s.privileged,
                **(
                    {"training_seeds": {"trained": list(seeded.trained), "shipped": seeded.shipped}}
                    if (seeded := plan.training_seeds.get(s.label))
                    else {}
                ),
            }
            for s in plan.agents
        ],
        "backend": {"name": config.resolved_backend(), "workers": config.resolved_workers()},
        "timing": {
            "wall_clock_s": seconds,
            "episodes": len(plan.tasks),
            **({"twin_episodes": len(plan.twin_tasks)} if plan.twin_tasks else {}),
            **videos,
        },
    }


def write_episode_plots(plan: Plan, directory: Path) -> list[Path]:
    """Per-episode figures of the first seed of every agent x scenario (run again, in process)."""
    from capture_bench.evaluation.reporting.plots import episode_figure

    directory.mkdir(parents=True, exist_ok=True)
    written = []
    try:
        for spec in plan.agents:
            for name in plan.scenarios:
                seed = plan.seeds[name][0]
                record, trace = run_task(EpisodeTask(spec.spec, name, seed), trace=True)
                assert trace is not None
                path = directory / episode_file_name(spec.label, scenario_label(name), seed, ".png")
                path.write_bytes(episode_figure(record, trace))
                written.append(path)
    finally:
        close_envs()
    return written


def video_jobs(
    plan: Plan,
    config: EvaluationConfig,
    records: Sequence[EpisodeRecord],
    ranking: Sequence[RankingRow],
) -> tuple[list[VideoKey], list[VideoKey], dict[VideoKey, tuple[EpisodeTask, int]]]:
    """The report's episodes to watch (if the suite has ``videos``) and ``--video``'s episodes
    (``records`` in ``plan.tasks`` order): their keys (agent, scenario, seed), and the jobs that
    record them, each episode once, by key: ``(task, its length in steps)`` for
    `record_video`."""
    played = {(r.agent, r.scenario, r.seed): (t, r) for t, r in zip(plan.tasks, records)}
    watched: list[VideoKey] = []
    if plan.suite.videos:
        learned = {s.label for s in plan.agents if s.kind == "model"}
        for w in choose_episodes(records, ranking, plan.suite.reference, learned):
            watched += [(agent, w.scenario, w.seed) for agent in w.agents]
    requested: list[VideoKey] = []
    if config.video is not None:
        requested = [
            (r.agent, r.scenario, r.seed)
            for t, r in zip(plan.tasks, records)
            if t.seed in plan.seeds[t.scenario][: config.video_episodes]
        ]
    keys = dict.fromkeys([*watched, *requested])
    return watched, requested, {key: (played[key][0], played[key][1].steps) for key in keys}


def make_report_media(
    data: ReportData, jobs: Sequence[tuple[EpisodeTask, int]], workers: int
) -> tuple[list[EpisodeVideo], dict[str, bytes] | None]:
    """The GIFs of ``jobs`` (in their order) and, with several ``workers``, the report's figures:
    all in a pool of local processes (`map_processes`:
    the figures split in groups of about equal cost, then the GIFs, as one list of work), else
    the GIFs in this process and the figures left for `write_report`. Either way the same
    bytes: an episode renders, and a figure draws, the same wherever it runs."""
    if workers <= 1:
        return [_report_job(("video", job)) for job in jobs], None
    groups = figure_groups(data, 2 * workers)
    work: list[tuple[str, Any]] = [("figures", (data, group)) for group in groups]
    work += [("video", job) for job in jobs]
    done = map_processes(_report_job, work, workers)
    drawn: dict[str, bytes] = {}
    for images in done[: len(groups)]:
        drawn.update(images)
    return done[len(groups) :], drawn


def _report_job(job: tuple[str, Any]) -> Any:
    """One piece of the report's media, a pool's unit of work: ``("video", (task, steps))`` ->
    `EpisodeVideo`, or ``("figures", (data, names))`` -> {name: PNG bytes}."""
    kind, payload = job
    if kind == "video":
        return record_video(*payload)
    data, names = payload
    return figures(data, names)


def summarise_in_pool(
    records: Sequence[EpisodeRecord], reference: str, workers: int
) -> list[Summary]:
    """`summarise_all`, with several ``workers`` in a
    pool of local processes (the cells dealt out in turn to ``2 * workers`` groups: their
    bootstraps are most of the cost), else in this process; the same summaries either way."""
    cells = summary_cells(records, reference)
    if workers <= 1 or len(cells) < 2:
        return summarise_cells(cells)
    count = min(2 * workers, len(cells))
    groups = [list(range(g, len(cells), count)) for g in range(count)]
    done = map_processes(summarise_cells, [[cells[i] for i in group] for group in groups], workers)
    summaries: list[Summary | None] = [None] * len(cells)
    for group, made in zip(groups, done, strict=True):
        for i, summary in zip(group, made, strict=True):
            summaries[i] = summary
    return [s for s in summaries if s is not None]


def training_seed_scores(
    plan: Plan, records: Sequence[EpisodeRecord], seed_records: Sequence[EpisodeRecord]
) -> dict[str, seed_report.SeedScores]:
    """Per agent with training seeds, its scores over them (`seed_report.compute`): the
    shipped seed's episodes are the agent's ``records``, each other seed's its records among
    ``seed_records`` (in ``plan.seed_tasks`` order)."""
    out = {}
    for label, seeds in plan.training_seeds.items():
        by_seed = {seeds.shipped: [r for r in records if r.agent == label]}
        for seed, spec in seeds.specs.items():
            played = zip(plan.seed_tasks, seed_records, strict=True)
            by_seed[seed] = [r for task, r in played if task.agent == spec]
        out[label] = seed_report.compute(by_seed, seeds.shipped)
    return out


def run_evaluation(
    plan: Plan,
    config: EvaluationConfig,
    command: str,
    progress: Callable[[int], None] | None = None,
) -> tuple[ReportData, Path]:
    """Run the plan's episodes, aggregate them and write the report.

    With the ``process`` backend the GIFs and the figures are made by worker processes
    (`make_report_media`).

    Returns:
        ``(report data, report directory)``.
    """
    start = time.perf_counter()
    backend, workers = config.resolved_backend(), config.resolved_workers()
    played = run_tasks(
        [*plan.tasks, *plan.seed_tasks, *plan.twin_tasks],
        backend,
        workers,
        config.ray_address,
        progress,
    )
    records: list[EpisodeRecord] = played[: len(plan.tasks)]
    seeded = len(plan.tasks) + len(plan.seed_tasks)
    seed_scores = training_seed_scores(plan, records, played[len(plan.tasks) : seeded])
    twin_records = played[seeded:]
    summaries = summarise_in_pool(
        records, plan.suite.reference, workers if backend == "process" else 1
    )
    privileged = {s.label for s in plan.agents if s.privileged}
    unranked = [scenario_label(n) for n in plan.scenarios if not load_scenario(n).ranked]
    ranking = rank_agents(summaries, privileged, unranked=unranked)
    seconds = time.perf_counter() - start
    data = ReportData(
        suite=plan.report_name,
        description=plan.description,
        command=command,
        reference=plan.suite.reference,
        records=records,
        summaries=summaries,
        ranking=ranking,
        provenance={},
        videos=[],
        training_seeds=seed_scores,
        twin_records=twin_records,
    )
    watched_keys, requested_keys, jobs = video_jobs(plan, config, records, ranking)
    videos, drawn = make_report_media(
        data, list(jobs.values()), workers if backend == "process" else 1
    )
    made = dict(zip(jobs, videos, strict=True))
    watched, requested = [made[k] for k in watched_keys], [made[k] for k in requested_keys]
    media_timing = {
        "videos": len(made),  # each recorded once
        "media_wall_clock_s": time.perf_counter() - start - seconds,
    }
    data = replace(
        data,
        provenance=_provenance(plan, config, command, seconds, media_timing),
        videos=watched,
    )
    target = write_report(data, config.out, drawn)
    if config.video is not None:
        write_videos(requested, config.video)
    if config.episode_plots is not None:
        write_episode_plots(plan, config.episode_plots)
    return data, target
