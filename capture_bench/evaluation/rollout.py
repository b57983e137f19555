"""One episode of one agent on one seed -> one :class:`EpisodeRecord`.

The loop follows Stable-Baselines3's ``evaluate_policy``: ``reset(seed)``, then ``predict`` /
``step`` until ``terminated or truncated``. Everything the leaderboard needs is read from the
environment's ``info`` (see ``docs/architecture.md``); nothing is read from the world directly.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np

from capture_bench.agents.protocol import Agent

CAPTURED = "captured"
FAILED = "failed"
#: Reason recorded when a failed episode's info names none (should not happen; kept visible).
UNSPECIFIED_FAILURE = "unspecified"
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
        distance_at_capture: true end-effector-target distance on the capture step, m; NaN if
            failed.
        relative_speed_at_capture: relative speed on the capture step, m/s; NaN if failed.
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


EPISODE_COLUMNS: tuple[str, ...] = tuple(f.name for f in fields(EpisodeRecord))
TIMING_COLUMNS: frozenset[str] = frozenset({"wall_clock_s", "cpu_s"})


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


def _float(info: dict[str, Any], key: str) -> float:
    value = info.get(key)
    return math.nan if value is None else float(value)


def _seed_agent(agent: Agent, env: Any, seed: int) -> None:
    """Make stochastic agents reproducible per episode, whatever process runs the episode."""
    env.action_space.seed(seed)
    seeder = getattr(agent, "seed", None)
    if callable(seeder):
        seeder(seed)


def _physical_limit_time(env: Any, info: dict[str, Any]) -> float:
    if info.get("physical_limit_time") is not None:
        return float(info["physical_limit_time"])
    return float(env.unwrapped.physical_limit().time)


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
    """Run one episode and summarise it.

    Args:
        env: a ``CaptureEnv`` (possibly wrapped, e.g. by ``TimeLimit``).
        agent: anything following :class:`capture_bench.agents.protocol.Agent`.
        agent_name: label stored in the record.
        scenario: scenario name stored in the record.
        seed: passed to ``env.reset(seed=seed)``, and to ``agent.seed`` if the agent has one.
        deterministic: passed to ``agent.predict``.
        trace: also return the per-step :class:`EpisodeTrace`.

    Returns:
        ``(record, trace or None)``.
    """
    _seed_agent(agent, env, seed)
    agent.reset()
    obs, info = env.reset(seed=seed)
    env.unwrapped.physical_limit()  # needed at the end anyway; now, so the clocks time steps only
    start, cpu_start = time.perf_counter(), time.process_time()
    state: Any = None
    episode_start = np.ones((1,), dtype=bool)
    pos_sq: list[float] = []
    vel_sq: list[float] = []
    nees: list[float] = []
    saturated = 0
    steps = 0
    series: dict[str, list[Any]] = {k: [] for k in ("time", "distance", "err", "action", "sat")}
    terminated = truncated = False
    while not (terminated or truncated):
        action, state = agent.predict(
            obs, state=state, episode_start=episode_start, deterministic=deterministic
        )
        episode_start = np.zeros((1,), dtype=bool)
        obs, _reward, terminated, truncated, info = env.step(action)
        steps += 1
        pos_sq.append(_float(info, "estimate_position_error") ** 2)
        vel_sq.append(_float(info, "estimate_velocity_error") ** 2)
        nees.append(_float(info, "estimate_nees"))
        saturated += bool(info.get("saturated", False))
        if trace:
            series["time"].append(_float(info, "time"))
            series["distance"].append(_float(info, "distance"))
            series["err"].append(_float(info, "estimate_position_error"))
            series["action"].append(np.asarray(action, dtype=float).reshape(-1))
            series["sat"].append(bool(info.get("saturated", False)))
        if steps >= MAX_STEPS:
            raise RuntimeError(f"episode of {agent_name} on {scenario} seed {seed} never ended")

    captured = bool(info.get("is_success", False))
    failure = "" if captured else (info.get("failure") or ("timeout" if truncated else None))
    if not captured and not failure:
        failure = UNSPECIFIED_FAILURE
    capture_time = _float(info, "capture_time") if captured else math.nan
    limit = _physical_limit_time(env, info)
    ratio = capture_time / limit if captured and math.isfinite(limit) and limit > 0 else math.nan
    finite_nees = [v for v in nees if math.isfinite(v)]
    record = EpisodeRecord(
        agent=agent_name,
        scenario=scenario,
        seed=int(seed),
        outcome=CAPTURED if captured else FAILED,
        failure=str(failure),
        capture_time=capture_time,
        end_time=_float(info, "time"),
        physical_limit_time=limit,
        ratio=ratio,
        capture_time_estimated=_float(info, "capture_time_estimated"),
        distance_at_capture=_float(info, "distance") if captured else math.nan,
        relative_speed_at_capture=_float(info, "relative_speed") if captured else math.nan,
        position_rmse=float(np.sqrt(np.nanmean(pos_sq))) if pos_sq else math.nan,
        velocity_rmse=float(np.sqrt(np.nanmean(vel_sq))) if vel_sq else math.nan,
        mean_nees=float(np.mean(finite_nees)) if finite_nees else math.nan,
        path_length=_float(info, "path_length"),
        saturated_share=saturated / steps if steps else math.nan,
        steps=steps,
        wall_clock_s=time.perf_counter() - start,
        cpu_s=time.process_time() - cpu_start,
    )
    episode_trace = None
    if trace:
        episode_trace = EpisodeTrace(
            time=np.array(series["time"]),
            distance=np.array(series["distance"]),
            position_error=np.array(series["err"]),
            action=np.array(series["action"]).reshape(steps, -1),
            saturated=np.array(series["sat"]),
        )
    return record, episode_trace
