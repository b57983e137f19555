"""Where episodes run: in this process, in a local process pool, or on a Ray cluster.

Work is a list of `EpisodeTask` (agent spec, scenario, seed: plain, picklable values). It is
cut into chunks of every agent on a few seeds of one scenario, each chunk runs in one worker, and
the records come back in the order of the tasks, whatever the backend and whatever order chunks
finish in. In a chunk, each agent's episodes are played together in one batched env
([`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv], autoreset off: `run_batch`),
sub-env i from ``reset(seed=s_i)``. Each worker builds its own environments (cached for its life;
the batched env records each seed's target side, camera and estimator included, as the single
env does, once, and replays it for the chunk's other agents), so every backend gives the same
records (apart from the timing columns), and they equal a single ``CaptureEnv``'s, episode by
episode.

The local pool's workers end with the process that started them, however it ends (``kill -9``
included), and the forkserver and multiprocessing's resource tracker then end by themselves.

Ray is imported only by the ``ray`` backend (``pip install capture-bench[ray]``), which starts
a new local instance on the loopback (no ``--ray-address``) or joins the cluster given, as
`capture_bench.ray_cluster` says (this checkout shipped to the workers;
`check_ray_cluster` refuses a cluster that does not answer, in
seconds). Model specs travel as written: name them ``models/<name>``.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from capture_bench.engine.cache import EpisodeCache
from capture_bench.evaluation.errors import EvaluationError
from capture_bench.evaluation.running.agents_loading import (
    AgentSpec,
    build_agent,
    declares_sampled_actions,
    resolve_agent,
)
from capture_bench.evaluation.running.rollout import (
    EpisodeRecord,
    EpisodeTrace,
    run_episode,
    run_episodes,
)
from capture_bench.interrupts import interrupts_deferred
from capture_bench.ray_cluster import import_ray, start_ray
from capture_bench.worker_processes import (
    end_with_parent,
    process_context,
    single_threaded_children,
)

BACKENDS = ("serial", "process", "ray")
#: Most seeds per chunk (each with every agent): the batch each agent plays at once. A batched
#: step has a fixed cost, so the larger the batch the less each episode pays (the default suite's
#: grasp scenario, 100 seeds, every agent, one core: less CPU in one chunk than in four).
SEEDS_PER_CHUNK = 100
#: Fewest seeds per chunk where several workers share the work (see `make_chunks`).
MIN_SEEDS_PER_CHUNK = 25

#: Modules the forkserver imports once, so that each worker starts with them loaded: the
#: episodes' (torch and Stable-Baselines3 for the trained models, a slow import in each worker
#: otherwise, at its first chunk) and the report media's (not ``matplotlib.pyplot``: imported
#: there before `capture_bench.evaluation.reporting.plots` selects its backend, it drew one
#: figure in other bytes).
#: The server imports them while the main process plans.
PRELOAD = (
    "capture_bench.evaluation.running.backends",
    "capture_bench.envs.capture_env",
    "capture_bench.agents",
    "capture_bench.evaluation.pipeline",
    "PIL.Image",
    "torch",
    "stable_baselines3",
)

#: The option that asks for Ray, as its messages name it.
RAY_BACKEND = "--backend ray"

Progress = Callable[[int], None]


@dataclass(frozen=True)
class EpisodeTask:
    """One episode to run: agent spec (string, see agents_loading), scenario name, seed, and
    whether the user allowed this agent's model to be unpickled (``--trust-model``)."""

    agent: str
    scenario: str
    seed: int
    trust_model: bool = False


_ENVS: dict[str, Any] = {}
_SPECS: dict[tuple[str, bool], AgentSpec] = {}
#: The recordings this process's envs share: a chunk's seeds, recorded once for all its agents,
#: whether they play in the batched env or in the single env (the oracle).
_RECORDINGS = EpisodeCache(max_episodes=2 * SEEDS_PER_CHUNK)


def make_env(scenario: str, **kwargs: Any) -> Any:
    """The gymnasium environment of a shipped scenario (``CaptureBench/<Name>-v1``), of a
    scenario file given by path, or of a shipped scenario's truth-fed twin (``<X>_truth``)."""
    import gymnasium
    from gymnasium.envs.registration import EnvSpec

    import capture_bench  # noqa: F401  (registers the environment IDs)
    from capture_bench.task.scenarios import load_scenario, truth_twin_base

    loaded = load_scenario(scenario)
    given: str | Any = None  # what the unregistered env is built from
    if Path(scenario).suffix in (".yaml", ".yml"):  # a file given by path: not registered
        given = str(Path(scenario).resolve())
    elif truth_twin_base(scenario) is not None:  # derived in code: not registered
        given = loaded
    if given is not None:
        spec = EnvSpec(
            id=loaded.env_id,
            entry_point="capture_bench.envs.capture_env:CaptureEnv",
            kwargs={"scenario": given},
        )
        return gymnasium.make(spec, **kwargs)
    return gymnasium.make(loaded.env_id, **kwargs)


def scenario_label(scenario: str) -> str:
    """The name a scenario spec has in reports: its own name (a file given by path: the name in
    the file, or its stem), never the path."""
    if Path(scenario).suffix in (".yaml", ".yml"):
        from capture_bench.task.scenarios import load_scenario

        return load_scenario(scenario).name
    return scenario


def _env(scenario: str, spec: AgentSpec) -> Any:
    """This process's single env of ``scenario`` for ``spec``'s observation (the estimate, or
    the camera's pixels), cached."""
    options = spec.env_options()
    key = f"{scenario}{options}"
    if key not in _ENVS:
        _ENVS[key] = make_env(
            scenario, reuse_target_side=True, episode_cache=_RECORDINGS, **options
        )
    return _ENVS[key]


def _vector_env(scenario: str, n: int, spec: AgentSpec) -> Any:
    """This process's batched env of ``n`` sub-envs of ``scenario`` for ``spec``'s observation,
    autoreset off (cached for the process's life, as the single envs are). It records each
    seed's target side once, to the time limit, in the process's cache, which the single envs
    share: the chunk's other agents replay it."""
    options = spec.env_options()
    key = f"{scenario}#{n}{options}"
    if key not in _ENVS:
        from gymnasium.vector import AutoresetMode

        from capture_bench.envs.vector_env import CaptureVectorEnv
        from capture_bench.task.scenarios import load_scenario

        _ENVS[key] = CaptureVectorEnv(
            n,
            load_scenario(scenario),
            autoreset_mode=AutoresetMode.DISABLED,
            episode_cache=_RECORDINGS,
            **options,
        )
    return _ENVS[key]


def close_envs() -> None:
    """Close and forget this process's cached environments and their recordings."""
    while _ENVS:
        _ENVS.popitem()[1].close()
    _RECORDINGS.clear()


def task_spec(task: EpisodeTask) -> AgentSpec:
    """The task's agent spec, resolved once per process."""
    key = (task.agent, task.trust_model)
    if key not in _SPECS:
        _SPECS[key] = resolve_agent(task.agent, trust_model=task.trust_model)
    return _SPECS[key]


def run_task(
    task: EpisodeTask, trace: bool = False, env: Any = None
) -> tuple[EpisodeRecord, EpisodeTrace | None]:
    """Run one task in this process in a single env (cached per scenario; agent built afresh).

    ``env``: run on this environment of the task's scenario instead of the cached one (a
    rendering one, `capture_bench.evaluation.running.video`), by the same steps: the same episode.
    """
    spec = task_spec(task)
    env = _env(task.scenario, spec) if env is None else env
    agent = build_agent(spec, env, task.seed)
    return run_episode(
        env,
        agent,
        agent_name=spec.label,
        scenario=scenario_label(task.scenario),
        seed=task.seed,
        trace=trace,
    )


def run_batch(tasks: Sequence[EpisodeTask]) -> list[EpisodeRecord]:
    """Run one agent's tasks on one scenario together, in a batched env with autoreset off
    (`run_episodes`); their records, in order.

    A ``batched`` agent is built once and asked once per step for every episode. A trained
    model is built once and asked once per step through ``predict_rows``: one forward pass
    whose rows are, bit for bit, the model's action for each observation alone
    (`capture_bench.agents.row_exact`; torch's plain batched product rounds a row by the
    batch's height, and the leaderboard's actions must be those the model card replays and a
    single env gives). Any other agent, a user's class written for one observation, is built
    once per episode, and each instance is asked with its own episode's observation; so is a
    privileged agent (the oracle), each built on its episode's sub-env
    (`sub_env`: the single env's ground
    truth, read from the batched env). A model declaring sampled actions (torch's one
    generator, seeded per episode) plays its episodes one by one in the single env, and so does
    every agent on a scenario with the rendered camera. Every way gives the single env's
    records (tested).
    """
    first = tasks[0]
    spec = task_spec(first)
    seeds = [task.seed for task in tasks]
    if declares_sampled_actions(spec) or _rendered(first.scenario):
        return [run_task(task)[0] for task in tasks]
    env = _vector_env(first.scenario, len(seeds), spec)
    if spec.privileged:  # one per episode, each reading its own sub-env's ground truth
        agent = [build_agent(spec, env.sub_env(i), seed) for i, seed in enumerate(seeds)]
    else:
        agent = build_agent(spec, env, seeds[0])
        if not (getattr(agent, "batched", False) or callable(getattr(agent, "predict_rows", None))):
            agent = [agent, *(build_agent(spec, env, seed) for seed in seeds[1:])]
    return run_episodes(
        env, agent, agent_name=spec.label, scenario=scenario_label(first.scenario), seeds=seeds
    )


def _rendered(scenario: str) -> bool:
    """Whether the scenario's camera is rendered: its frames show the arm, so each episode runs
    in the worker's single env, which renders each seed's target-only frames once for all the
    chunk's agents (`capture_bench.sensing.scene_camera`)."""
    from capture_bench.task.scenarios import load_scenario

    return load_scenario(scenario).camera.mode == "rendered"


def run_chunk(tasks: Sequence[EpisodeTask]) -> list[EpisodeRecord]:
    """Run a chunk in this process, the unit of work of every backend: each agent's episodes on
    a scenario as one batch (`run_batch`); the records in task order."""
    groups: dict[tuple[str, bool, str], list[int]] = {}
    for index, task in enumerate(tasks):
        groups.setdefault((task.agent, task.trust_model, task.scenario), []).append(index)
    records: dict[int, EpisodeRecord] = {}
    for indices in groups.values():
        batch = run_batch([tasks[i] for i in indices])
        records.update(zip(indices, batch, strict=True))
    return [records[i] for i in range(len(tasks))]


def make_chunks(
    tasks: Sequence[EpisodeTask], seeds: int = SEEDS_PER_CHUNK, workers: int = 1
) -> list[list[int]]:
    """Indices of ``tasks`` grouped into chunks: every task of one scenario on up to ``seeds`` of
    its seeds (in the order they first appear), whatever the agent, in task order.

    With several ``workers`` the chunks shrink towards the end (guided scheduling): a chunk opened
    while R (scenario, seed) pairs are still to be placed holds up to ``ceil(R / (2 workers))``
    seeds, at least `MIN_SEEDS_PER_CHUNK` (and at most ``seeds``; a scenario's remainder
    below that joins the chunk before it), so the workers, taking chunks in order, finish close
    together: the last chunks are the small ones.
    """
    unplaced: dict[str, set[int]] = {}  # scenario -> its seeds not yet in a chunk
    for task in tasks:
        unplaced.setdefault(task.scenario, set()).add(task.seed)
    pairs = sum(map(len, unplaced.values()))
    chunks: list[list[int]] = []
    chunk_of: dict[tuple[str, int], int] = {}  # (scenario, seed) -> chunk
    filling: dict[str, tuple[int, int, int]] = {}  # scenario -> (newest chunk, seeds, its size)
    for index, task in enumerate(tasks):
        key = (task.scenario, task.seed)
        if key not in chunk_of:
            chunk, count, size = filling.get(task.scenario, (-1, 0, 0))
            if count == size:
                remaining = pairs - len(chunk_of)
                guided = -(-remaining // (2 * workers)) if workers > 1 else seeds
                size = max(1, min(seeds, max(guided, MIN_SEEDS_PER_CHUNK)))
                left = len(unplaced[task.scenario])
                if left - size < MIN_SEEDS_PER_CHUNK and left <= seeds:
                    size = left
                chunk, count = len(chunks), 0
                chunks.append([])
            filling[task.scenario] = (chunk, count + 1, size)
            chunk_of[key] = chunk
            unplaced[task.scenario].discard(task.seed)
        chunks[chunk_of[key]].append(index)
    return chunks


def _run_serial(chunks: list[list[EpisodeTask]], progress: Progress) -> list[list[EpisodeRecord]]:
    results = []
    try:
        for chunk in chunks:
            results.append(run_chunk(chunk))
            progress(len(chunk))
    finally:
        close_envs()
    return results


def _run_process(
    chunks: list[list[EpisodeTask]], workers: int, progress: Progress
) -> list[list[EpisodeRecord]]:
    return map_processes(run_chunk, chunks, workers, lambda i: progress(len(chunks[i])))


def _process_context() -> Any:
    """The workers' start method's context, the forkserver preloading `PRELOAD`."""
    return process_context(PRELOAD)


def prestart_workers() -> None:
    """Start the forkserver now, so that it imports `PRELOAD` while this process plans
    the evaluation (two cores: side by side); the first pool's workers then fork at once.
    Nothing where there is no forkserver. The server ends with this process."""
    if _process_context().get_start_method() == "forkserver":
        import multiprocessing.forkserver

        with single_threaded_children():
            multiprocessing.forkserver.ensure_running()


def map_processes(
    function: Callable[[Any], Any],
    items: Sequence[Any],
    workers: int,
    done: Callable[[int], None] | None = None,
) -> list[Any]:
    """``[function(item) for item in items]`` in a pool of ``workers`` local processes (forked
    from a server that has imported `PRELOAD`, one numerical thread each); ``done(i)`` is
    called as item i's result arrives. ``function`` and the items must pickle (a module-level
    function). The workers end with this process however it ends, and on any error here
    (Ctrl-C, SIGTERM, a failed item) they are killed before the error propagates."""
    context = _process_context()
    results: list[Any] = [None] * len(items)
    workers = max(1, min(workers, len(items)))
    # Only this process holds `held`: the workers see end-of-file on `watched` when it ends.
    watched, held = context.Pipe(duplex=False)
    pool = ProcessPoolExecutor(
        workers, mp_context=context, initializer=_start_worker, initargs=(watched,)
    )
    try:
        # The workers (and the forkserver) start on submit. An interrupt waits until each has
        # started and is in the pool's record, which _kill_workers reads: one cut off as it
        # started would be missed by the kill, and fail to read its start-up data (a traceback)
        # once this process is gone.
        with interrupts_deferred(), single_threaded_children():
            pending = {pool.submit(function, item): i for i, item in enumerate(items)}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                index = pending.pop(future)
                results[index] = future.result()
                if done is not None:
                    done(index)
    except BaseException:  # Ctrl-C, SIGTERM, a failed item: stop now, leave no worker behind
        _kill_workers(pool)
        raise
    else:
        pool.shutdown(wait=True)
    finally:
        held.close()
        watched.close()
    return results


def _start_worker(watched: Connection) -> None:
    """Worker initialiser. SIGINT (Ctrl-C reaches the whole process group) and SIGTERM are the
    main process's to handle: it kills the workers itself. And the worker ends with the main
    process, however that ends (`end_with_parent`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    end_with_parent(watched, _exit_now)


def _exit_now() -> None:
    os._exit(1)  # at once, even mid-episode: nothing is left to receive the results


def _kill_workers(pool: ProcessPoolExecutor) -> None:
    """End a pool at once: cancel what has not started, kill the workers (which ignore SIGINT
    and SIGTERM), and shut down without waiting for running chunks (a graceful shutdown waits
    for every running chunk: minutes)."""
    processes = list(getattr(pool, "_processes", {}).values())  # the executor's own record
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.kill()
    for process in processes:
        process.join(timeout=5)


def _run_ray(
    chunks: list[list[EpisodeTask]], address: str | None, progress: Progress
) -> list[list[EpisodeRecord]]:
    ray = import_ray(RAY_BACKEND)
    started = start_ray(address, RAY_BACKEND)
    try:
        remote = ray.remote(num_cpus=1)(run_chunk)
        refs = {remote.remote(chunk): i for i, chunk in enumerate(chunks)}
        results: list[list[EpisodeRecord] | None] = [None] * len(chunks)
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                index = refs[ref]
                results[index] = ray.get(ref)
                progress(len(chunks[index]))
    finally:
        if started:
            ray.shutdown()
    return [r for r in results if r is not None]


def run_tasks(
    tasks: Sequence[EpisodeTask],
    backend: str = "serial",
    workers: int = 1,
    ray_address: str | None = None,
    progress: Progress | None = None,
) -> list[EpisodeRecord]:
    """Run every task and return the records in task order.

    Args:
        tasks: the episodes to run.
        backend: ``serial``, ``process`` (``workers`` local processes) or ``ray``.
        workers: process count of the ``process`` backend (>= 1).
        ray_address: Ray cluster address for the ``ray`` backend (None: local or already running).
        progress: called with the number of episodes just finished.
    """
    if backend not in BACKENDS:
        raise EvaluationError(f"unknown backend {backend!r}; valid: {', '.join(BACKENDS)}")
    if workers < 1:
        raise EvaluationError(f"--workers {workers}: expected a whole number >= 1")
    report = progress or (lambda _n: None)
    parallel = workers if backend == "process" else 1
    # A Ray cluster's size is its own: small chunks for as many of its CPUs as it has.
    seeds = MIN_SEEDS_PER_CHUNK if backend == "ray" else SEEDS_PER_CHUNK
    indices = make_chunks(tasks, seeds, parallel)
    while len(indices) < parallel and seeds > 1:  # keep workers busy
        seeds -= 1
        indices = make_chunks(tasks, seeds, parallel)
    chunks = [[tasks[i] for i in chunk] for chunk in indices]
    if backend == "serial" or (backend == "process" and workers == 1):
        nested = _run_serial(chunks, report)
    elif backend == "process":
        nested = _run_process(chunks, workers, report)
    else:
        nested = _run_ray(chunks, ray_address, report)
    by_index = {
        index: record
        for chunk, chunk_records in zip(indices, nested, strict=True)
        for index, record in zip(chunk, chunk_records, strict=True)
    }
    return [by_index[index] for index in range(len(tasks))]
