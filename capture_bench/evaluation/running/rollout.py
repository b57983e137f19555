"""Episodes of one agent -> one `EpisodeRecord` each.

`run_episodes` plays N episodes of one agent together in a
[`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv] with autoreset off, one
``predict`` call
per step for all of them (an agent that handles one observation at a time gets one instance per
episode instead); `run_episode` plays one in a single ``CaptureEnv`` (the privileged oracle,
sampled policies, rendered videos). Both follow Stable-Baselines3's ``evaluate_policy``:
``reset(seed)``, then ``predict`` / ``step`` until ``terminated or truncated``, and both make the
record from the environment's ``info`` alone (see ``docs/architecture.md``), by
`_EpisodeLog`, so an episode's record is the same whichever way it ran (tested).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import Any, get_type_hints

import numpy as np

from capture_bench.agents.protocol import Agent
from capture_bench.envs.vector_env import sub_env_infos
from capture_bench.task.accounting import (
    EstimateLog,
    Outcome,
    episode_outcome,
    info_number,
)

CAPTURED = "captured"
FAILED = "failed"
#: Safety net against an environment that never ends an episode.
MAX_STEPS = 1_000_000


@dataclass(frozen=True)
class EpisodeRecord:
    """Per-episode columns of ``episodes.csv``. NaN marks "not applicable" (e.g. no capture).

    Attributes:
        agent: agent label (built-in name, model name or ``module:Class``).
        scenario: scenario name (lowercase, e.g. ``paper``).
        seed: the evaluation seed passed to ``env.reset(seed=...)``.
        outcome: ``captured`` or ``failed``.
        failure: failure reason (``timeout``, ``collision``, ``target_lost``, ``unreachable``, ...),
            empty string if captured.
        capture_time: time of capture (true-position test, eq. 20), s; NaN if failed.
        end_time: simulated time when the episode ended (capture or failure), s.
        physical_limit_time: the episode's lower bound on capture time, s; inf if unreachable.
        ratio: capture_time / physical_limit_time (>= 1 up to tolerance); NaN if failed or the
            bound is not finite and positive.
        capture_time_estimated: first time the estimate-based test held, s; NaN if never.
        distance_at_capture: true end-effector-target distance ||X_E - X_T|| at the capture
            instant (within the capture step, where the capture completed), m; NaN if failed.
        relative_speed_at_capture: the end-effector's instantaneous speed relative to the
            capture point at the capture instant, ``|J(theta) dtheta/dt - Xdot_T|``, m/s; NaN
            if failed.
        relative_speed_max_over_hold: the largest instantaneous relative speed over the hold,
            from the captured stay's entry to the capture (with hold 0 it is
            ``relative_speed_at_capture``), m/s, sampled along each step as
            `capture_times` says; NaN if failed.
        position_rmse: RMS over steps of the estimated target position error, m.
        velocity_rmse: RMS over steps of the estimated target velocity error, m/s.
        mean_nees: mean over steps of the 6-dof position/velocity NEES (NaN steps skipped).
        path_length: end-effector path length over the episode, m.
        saturated_share: share of steps in which some joint ran at its rate limit, in [0, 1].
        steps: number of control steps taken.
        wall_clock_s: wall-clock time of the episode's steps (the agent's decisions and the env's
            steps), s; reset and the physical-limit bound, which a worker computes for the first
            agent of each seed and reuses for the others, are not counted (a timing column: not
            reproducible).
        cpu_s: CPU time of the same, in its process, s (timing column; unlike the wall clock it
            does not grow when other processes compete for the cores).
    """

    agent: str
    scenario: str
    seed: int
    outcome: str
    failure: str
    capture_time: float
    end_time: float
    physical_limit_time: float
    ratio: float
    capture_time_estimated: float
    distance_at_capture: float
    relative_speed_at_capture: float
    # keyword-only with a default, so that a record written without it (a synthetic one) is NaN
    relative_speed_max_over_hold: float = field(default=math.nan, kw_only=True)
    position_rmse: float
    velocity_rmse: float
    mean_nees: float
    path_length: float
    saturated_share: float
    steps: int
    wall_clock_s: float = field(compare=False)
    cpu_s: float = field(default=math.nan, compare=False)

    @property
    def captured(self) -> bool:
        """True if the episode ended in a capture."""
        return self.outcome == CAPTURED

    def as_row(self) -> dict[str, Any]:
        """The record as a flat dict in column order."""
        return asdict(self)

    @classmethod
    def from_row(cls, row: Mapping[str, str | None]) -> EpisodeRecord:
        """The record of one ``episodes.csv`` row as `csv.DictReader` reads it: the inverse
        of `as_row` written through ``report.csv_value`` (floats in repr, NaN as an empty
        cell), every field exact. Raises ValueError naming a missing or unreadable column."""
        values: dict[str, Any] = {}
        for name, kind in _FIELD_TYPES.items():
            text = row.get(name)
            if text is None:
                raise ValueError(f"no column {name!r}")
            try:
                values[name] = _cell(text, kind)
            except ValueError:
                raise ValueError(
                    f"column {name!r}: {text!r} cannot be read as {kind.__name__}"
                ) from None
        return cls(**values)


EPISODE_COLUMNS: tuple[str, ...] = tuple(f.name for f in fields(EpisodeRecord))
TIMING_COLUMNS: frozenset[str] = frozenset({"wall_clock_s", "cpu_s"})
#: Each column's Python type (str, int or float), in column order.
_FIELD_TYPES: dict[str, type] = get_type_hints(EpisodeRecord)


def _cell(text: str, kind: type) -> Any:
    """A CSV cell's value as ``kind``: an empty float cell is NaN, a float is read from its repr."""
    if kind is float:
        return math.nan if text == "" else float(text)
    if kind in (int, str):
        return kind(text)
    raise TypeError(f"no reader for a {kind.__name__} column")


@dataclass(frozen=True)
class EpisodeTrace:
    """Per-step series of one episode, for the optional per-episode plots.

    Attributes:
        time: simulated time after each step, s, shape (T,).
        distance: true end-effector-target distance, m, shape (T,).
        position_error: estimated target position error, m, shape (T,).
        action: actions taken, in [-1, 1], shape (T, 3).
        saturated: whether some joint ran at its rate limit, shape (T,).
    """

    time: np.ndarray
    distance: np.ndarray
    position_error: np.ndarray
    action: np.ndarray
    saturated: np.ndarray


def _at_capture(outcome: Outcome, info: dict[str, Any], key: str) -> float:
    """The capturing step's ``info[key]`` (the values at the capture instant), NaN if the
    episode did not capture."""
    return info_number(info, key) if outcome.captured else math.nan


def seed_agent(agent: Agent, env: Any, seed: int) -> None:
    """Make stochastic agents reproducible per episode, whatever process runs the episode."""
    env.action_space.seed(seed)
    seeder = getattr(agent, "seed", None)
    if callable(seeder):
        seeder(seed)


def _physical_limit_time(env: Any, info: dict[str, Any]) -> float:
    if info.get("physical_limit_time") is not None:
        return float(info["physical_limit_time"])
    return float(env.unwrapped.physical_limit().time)


class _EpisodeLog(EstimateLog):
    """What an episode's record is made of, gathered step by step from ``info``
    (`capture_bench.task.accounting`), and the per-step series where asked."""

    def __init__(self, trace: bool = False) -> None:
        super().__init__()
        self.series: dict[str, list[Any]] | None = (
            {k: [] for k in ("time", "distance", "err", "action", "sat")} if trace else None
        )

    def add_step(self, info: dict[str, Any], action: Any) -> None:
        """One step's ``info`` (the single env's form) and the action taken."""
        self.add_info(info)
        if self.series is not None:
            self.series["time"].append(info_number(info, "time"))
            self.series["distance"].append(info_number(info, "distance"))
            self.series["err"].append(info_number(info, "estimate_position_error"))
            self.series["action"].append(np.asarray(action, dtype=float).reshape(-1))
            self.series["sat"].append(bool(info.get("saturated", False)))

    def record(
        self,
        info: dict[str, Any],
        truncated: bool,
        limit: float,
        *,
        agent_name: str,
        scenario: str,
        seed: int,
        wall_clock_s: float,
        cpu_s: float,
    ) -> EpisodeRecord:
        """The record, from the last step's ``info`` and the episode's physical limit, s."""
        outcome = episode_outcome(info, truncated, limit)
        return EpisodeRecord(
            agent=agent_name,
            scenario=scenario,
            seed=int(seed),
            outcome=CAPTURED if outcome.captured else FAILED,
            failure=outcome.failure,
            capture_time=outcome.capture_time,
            end_time=info_number(info, "time"),
            physical_limit_time=outcome.physical_limit_time,
            ratio=outcome.ratio,
            capture_time_estimated=info_number(info, "capture_time_estimated"),
            distance_at_capture=_at_capture(outcome, info, "distance_at_capture"),
            relative_speed_at_capture=_at_capture(outcome, info, "relative_speed_at_capture"),
            relative_speed_max_over_hold=_at_capture(outcome, info, "relative_speed_max_over_hold"),
            position_rmse=self.position_rmse,
            velocity_rmse=self.velocity_rmse,
            mean_nees=self.mean_nees,
            path_length=info_number(info, "path_length"),
            saturated_share=self.saturated_share,
            steps=self.steps,
            wall_clock_s=wall_clock_s,
            cpu_s=cpu_s,
        )

    def trace(self) -> EpisodeTrace | None:
        """The per-step series, if kept."""
        if self.series is None:
            return None
        return EpisodeTrace(
            time=np.array(self.series["time"]),
            distance=np.array(self.series["distance"]),
            position_error=np.array(self.series["err"]),
            action=np.array(self.series["action"]).reshape(self.steps, -1),
            saturated=np.array(self.series["sat"]),
        )


def run_episode(
    env: Any,
    agent: Agent,
    *,
    agent_name: str,
    scenario: str,
    seed: int,
    deterministic: bool = True,
    trace: bool = False,
) -> tuple[EpisodeRecord, EpisodeTrace | None]:
    """Run one episode in a single env and summarise it.

    Args:
        env: a ``CaptureEnv`` (possibly wrapped, e.g. by ``TimeLimit``).
        agent: anything following
        [`capture_bench.agents.protocol.Agent`][capture_bench.agents.protocol.Agent].
        agent_name: label stored in the record.
        scenario: scenario name stored in the record.
        seed: passed to ``env.reset(seed=seed)``, and to ``agent.seed`` if the agent has one.
        deterministic: passed to ``agent.predict``.
        trace: also return the per-step `EpisodeTrace`.

    Returns:
        ``(record, trace or None)``.
    """
    seed_agent(agent, env, seed)
    agent.reset()
    obs, info = env.reset(seed=seed)
    env.unwrapped.physical_limit()  # needed at the end anyway; now, so the clocks time steps only
    start, cpu_start = time.perf_counter(), time.process_time()
    state: Any = None
    episode_start = np.ones((1,), dtype=bool)
    log = _EpisodeLog(trace)
    terminated = truncated = False
    while not (terminated or truncated):
        action, state = agent.predict(
            obs, state=state, episode_start=episode_start, deterministic=deterministic
        )
        episode_start = np.zeros((1,), dtype=bool)
        obs, _reward, terminated, truncated, info = env.step(action)
        log.add_step(info, action)
        if log.steps >= MAX_STEPS:
            raise RuntimeError(f"episode of {agent_name} on {scenario} seed {seed} never ended")
    record = log.record(
        info,
        truncated,
        _physical_limit_time(env, info),
        agent_name=agent_name,
        scenario=scenario,
        seed=seed,
        wall_clock_s=time.perf_counter() - start,
        cpu_s=time.process_time() - cpu_start,
    )
    return record, log.trace()


#: ``info`` keys an episode's record gathers every step (`EstimateLog.add`).
_LOGGED = ("estimate_position_error", "estimate_velocity_error", "estimate_nees", "saturated")


def run_episodes(
    env: Any,
    agent: Agent | Sequence[Agent],
    *,
    agent_name: str,
    scenario: str,
    seeds: Sequence[int],
    deterministic: bool = True,
) -> list[EpisodeRecord]:
    """Run N episodes of one agent together and summarise each.

    Args:
        env: a [`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv] of N =
        ``len(seeds)``
            sub-envs with autoreset off (an ended sub-env stays ended).
        agent: one agent whose ``batched`` is true, asked once per step with every episode's
            observation, (N, 16), row i for episode i (an ended episode's row holds its last
            observation, and its action is ignored); or one agent with ``predict_rows`` (a
            trained model: each row's deterministic action as alone), asked once per step with
            the running episodes' observations; or N agents, one per episode, each asked with
            its own episode's observation while the episode runs (the fallback for agents
            written for one observation).
        agent_name: label stored in the records.
        scenario: scenario name stored in the records.
        seeds: episode seeds, one per sub-env (``env.reset(seed=list(seeds))``).
        deterministic: passed to ``predict``.

    Returns:
        One record per seed, in order, each equal to `run_episode`'s for that seed but for
        the timing columns: the batch's wall-clock and CPU time, shared between its episodes in
        proportion to their steps.
    """
    n = len(seeds)
    if n != env.num_envs:
        raise ValueError(f"{n} seeds for a vector env of {env.num_envs} sub-envs")
    each = isinstance(agent, Sequence)
    agents: list[Any] = list(agent) if isinstance(agent, Sequence) else [agent]
    if each and len(agents) != n:
        raise ValueError(f"{len(agents)} agents for {n} episodes: give one batched agent or N")
    rows_of = None if each else getattr(agent, "predict_rows", None)
    if not each and not (getattr(agent, "batched", False) or callable(rows_of)):
        raise ValueError(
            f"{agent_name} is not batched (its `batched` is not true and it has no "
            "predict_rows): give one agent per episode"
        )
    if rows_of is not None and not deterministic:
        raise ValueError("predict_rows gives deterministic actions: deterministic must be True")
    for one, seed in zip(agents, seeds, strict=False):
        seeder = getattr(one, "seed", None)
        if each and callable(seeder):
            seeder(seed)
        one.reset()
    obs, _info = env.reset(seed=[int(s) for s in seeds])
    start, cpu_start = time.perf_counter(), time.process_time()
    logs = [_EpisodeLog() for _ in range(n)]
    states: list[Any] = [None] * len(agents)
    running = np.ones(n, dtype=bool)
    first = True
    ends: list[tuple[dict[str, Any], bool] | None] = [None] * n
    actions = np.zeros((n, 3))  # float64: holds float32 and float64 actions exactly
    while running.any():
        rows: list[int] = np.flatnonzero(running).tolist()
        if each:
            for i in rows:
                actions[i], states[i] = agents[i].predict(
                    _rows(obs, i),
                    state=states[i],
                    episode_start=np.full((1,), first),
                    deterministic=deterministic,
                )
        elif rows_of is not None:  # each row as alone, so only the running episodes' rows
            actions[rows] = rows_of(_rows(obs, rows))
        else:  # every row, so that row i is always episode i; an ended one's is ignored
            batch, states[0] = agents[0].predict(
                obs,
                state=states[0],
                episode_start=np.full((n,), first),
                deterministic=deterministic,
            )
            actions[rows] = np.asarray(batch)[rows]
        first = False
        obs, _rewards, terminated, truncated, info = env.step(actions)
        position_error, velocity_error, nees, saturated = (info[k].tolist() for k in _LOGGED)
        ended = terminated | truncated
        infos = sub_env_infos(info, n) if ended.any() else []  # the last step's, in full
        for i in rows:  # the episodes that ran this step
            logs[i].add(position_error[i], velocity_error[i], nees[i], saturated[i])
            if ended[i]:
                ends[i] = (infos[i], bool(truncated[i]))
                running[i] = False
            elif logs[i].steps >= MAX_STEPS:
                raise RuntimeError(
                    f"episode of {agent_name} on {scenario} seed {seeds[i]} never ended"
                )
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    total = sum(log.steps for log in logs)
    records = []
    for log, end, seed in zip(logs, ends, seeds):
        assert end is not None
        row, was_truncated = end
        share = log.steps / total
        limit = row.get("physical_limit_time")
        records.append(
            log.record(
                row,
                was_truncated,
                math.nan if limit is None else float(limit),
                agent_name=agent_name,
                scenario=scenario,
                seed=seed,
                wall_clock_s=wall * share,
                cpu_s=cpu * share,
            )
        )
    return records


def _rows(obs: Any, index: Any) -> Any:
    """Rows ``index`` of a batch of observations: an array's, or each entry's of a dict (the
    pixel observation's image and state)."""
    if isinstance(obs, dict):
        return {key: value[index] for key, value in obs.items()}
    return obs[index]
