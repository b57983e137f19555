"""One episode of an agent as the arrays of a Minari episode (`EpisodeArrays`), staged one
``.npz`` file each (`save_episode`, `load_episode`: no pickle) and handed to Minari's storage as
its `EpisodeBuffer` (`to_buffer`).

Minari's layout: T steps give T + 1 observations (reset's first), T actions, rewards,
terminations and truncations, and T + 1 rows of every ``info`` entry (reset's first). The env's
reset ``info`` holds ``time`` and ``distance`` only; its other rows are NaN (numbers), False
(flags) or "" (text) there. ``failure`` is "" where the env gives None, and the optional numbers
(``capture_time`` ...) are NaN where it gives None. ``physical_limit_time``, in the last step's
``info`` only, is an episode's metadata, not a row. Beside the env's ``info``, every row holds
``estimate_covariance`` (6 x 6): the estimator's covariance P of the estimate's (position,
velocity) at that step, in the global frame (m, m/s), NaN where the estimator has none (no
estimate yet, photogrammetry alone, or the truth source); the observation's estimate is its mean.

The action recorded is the one stepped: the agent's action as float32 (the action space's
dtype), clipped to [-1, 1] (the env clips every action there anyway), so stepping the recorded
actions replays the episode exactly (``docs/datasets.md``). With ``privileged`` the rows also
hold the true target state at each step: ``true_target_position`` (global, m),
``true_target_velocity`` (m/s) and ``true_target_rotation`` (R_gt, 3 x 3).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from capture_bench.evaluation.running.rollout import seed_agent
from capture_bench.task.step_rule import END_INFO_KEYS

#: ``info`` entries that are text.
TEXT_INFO = ("failure", "estimator_status")
#: The true target state's rows, with ``privileged``: (name, the recording's track).
TRUE_STATE = (
    ("true_target_position", "position"),
    ("true_target_velocity", "velocity"),
    ("true_target_rotation", "rotation"),
)
#: The estimator's covariance of each row (module docstring).
COVARIANCE_INFO = "estimate_covariance"
_INFO_PREFIX = "info/"


@dataclass(eq=False)
class EpisodeArrays:
    """One recorded episode: Minari's arrays and what the episode's metadata says.

    Attributes:
        agent: the agent's label (built-in name, model name or ``module:Class``).
        seed: the seed ``env.reset(seed=...)`` was given.
        observations: (T + 1, 16) float32, reset's first.
        actions: (T, 3) float32, the actions stepped.
        rewards: (T,) float64.
        terminations: (T,) bool.
        truncations: (T,) bool.
        infos: each ``info`` entry's (T + 1, ...) rows (module docstring).
        end: the last step's `END_INFO_KEYS` (``physical_limit_time``, s).
    """

    agent: str
    seed: int
    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray
    infos: dict[str, np.ndarray]
    end: dict[str, float] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        """T, the number of steps."""
        return len(self.rewards)

    def metadata(self) -> dict[str, Any]:
        """The episode's metadata in the dataset (Minari keeps ``id`` and ``seed`` itself):
        the agent, the outcome and the return."""
        failure = str(self.infos["failure"][-1]) if "failure" in self.infos else ""
        captured = bool(self.terminations[-1]) and not failure
        capture = (
            float(self.infos["capture_time"][-1]) if "capture_time" in self.infos else math.nan
        )
        return {
            "agent": self.agent,
            "outcome": "captured" if captured else "failed",
            "failure": failure,
            "capture_time": capture,
            "physical_limit_time": float(self.end.get("physical_limit_time", math.nan)),
            "rewards_sum": float(np.sum(self.rewards)),
        }


def executed_action(action: Any) -> np.ndarray:
    """The action stepped and recorded: float32, clipped to [-1, 1], shape (3,)."""
    return np.clip(np.asarray(action, dtype=np.float32).reshape(-1), -1.0, 1.0)


class _Rows:
    """An episode's rows as they come: observations, actions, step results, ``info``s."""

    def __init__(self, env: Any, privileged: bool) -> None:
        self.env = env.unwrapped
        self.privileged = privileged
        self.observations: list[np.ndarray] = []
        self.actions: list[np.ndarray] = []
        self.results: list[tuple[float, bool, bool]] = []
        self.infos: list[dict[str, Any]] = []

    def add(self, observation: Any, info: dict[str, Any]) -> None:
        """The observation and ``info`` of reset or of a step, and the true state there."""
        self.observations.append(np.asarray(observation, dtype=np.float32))
        row = {k: v for k, v in info.items() if k not in END_INFO_KEYS}
        episode, k = self.env.recorded_episode, len(self.infos)
        row[COVARIANCE_INFO] = episode.estimate_covariance[k].copy()
        if self.privileged:
            row.update({name: getattr(episode, track)[k] for name, track in TRUE_STATE})
        self.infos.append(row)

    def arrays(self, agent: str, seed: int, last_info: dict[str, Any]) -> EpisodeArrays:
        rewards, terminations, truncations = zip(*self.results)
        return EpisodeArrays(
            agent=agent,
            seed=int(seed),
            observations=np.stack(self.observations),
            actions=np.stack(self.actions),
            rewards=np.asarray(rewards, dtype=np.float64),
            terminations=np.asarray(terminations, dtype=bool),
            truncations=np.asarray(truncations, dtype=bool),
            infos=info_arrays(self.infos),
            end={k: float(last_info[k]) for k in END_INFO_KEYS if k in last_info},
        )


def info_arrays(rows: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Each ``info`` entry's rows, in the order of the steps' keys (module docstring: what
    reset's row holds where it has no entry)."""
    keys = list(dict.fromkeys(k for row in rows[1:] for k in row)) or list(rows[0])
    return {key: _column(key, [row.get(key) for row in rows]) for key in keys}


def _column(key: str, values: list[Any]) -> np.ndarray:
    present = [v for v in values if v is not None]
    if key in TEXT_INFO or any(isinstance(v, str) for v in present):
        return np.asarray(["" if v is None else str(v) for v in values], dtype=str)
    if present and all(isinstance(v, (bool, np.bool_)) for v in present):
        return np.asarray([bool(v) for v in values], dtype=bool)
    shape = np.shape(present[0]) if present else ()
    return np.stack([np.full(shape, np.nan) if v is None else np.asarray(v, float) for v in values])


def play_episode(env: Any, agent: Any, *, label: str, seed: int, privileged: bool) -> EpisodeArrays:
    """Play one episode of ``agent`` (deterministic actions, as evaluation does) from
    ``env.reset(seed=seed)`` and return its arrays; a stochastic agent is seeded with ``seed``."""
    seed_agent(agent, env, seed)
    agent.reset()
    rows = _Rows(env, privileged)
    obs, info = env.reset(seed=seed)
    rows.add(obs, info)
    state: Any = None
    done, first = False, True
    while not done:
        action, state = agent.predict(
            obs, state=state, episode_start=np.array([first]), deterministic=True
        )
        first = False
        stepped = executed_action(action)
        obs, reward, terminated, truncated, info = env.step(stepped)
        rows.actions.append(stepped)
        rows.results.append((float(reward), bool(terminated), bool(truncated)))
        rows.add(obs, info)
        done = terminated or truncated
    return rows.arrays(label, seed, info)


def save_episode(path: Path, episode: EpisodeArrays) -> None:
    """Write ``episode`` to ``path`` (``.npz``) through a temporary file renamed onto it: a file
    under ``path`` is always a whole episode."""
    arrays = {
        "observations": episode.observations,
        "actions": episode.actions,
        "rewards": episode.rewards,
        "terminations": episode.terminations,
        "truncations": episode.truncations,
        **{_INFO_PREFIX + k: v for k, v in episode.infos.items()},
        "header": np.asarray(
            json.dumps({"agent": episode.agent, "seed": episode.seed, "end": episode.end})
        ),
    }
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    with open(tmp, "wb") as handle:
        np.savez(handle, **arrays)  # type: ignore[arg-type]
    os.replace(tmp, path)


def load_episode(path: Path) -> EpisodeArrays:
    """The episode `save_episode` wrote to ``path``."""
    with np.load(path, allow_pickle=False) as data:
        header = json.loads(str(data["header"]))
        infos = {k[len(_INFO_PREFIX) :]: data[k] for k in data.files if k.startswith(_INFO_PREFIX)}
        return EpisodeArrays(
            agent=header["agent"],
            seed=int(header["seed"]),
            observations=data["observations"],
            actions=data["actions"],
            rewards=data["rewards"],
            terminations=data["terminations"],
            truncations=data["truncations"],
            infos=infos,
            end=header["end"],
        )


def to_buffer(episode: EpisodeArrays, index: int) -> Any:
    """Minari's `EpisodeBuffer` of ``episode``, as episode ``index`` of its dataset (text rows as
    lists of ``str``, which Minari's HDF5 storage writes as UTF-8 strings)."""
    from minari.data_collector import EpisodeBuffer

    infos = {k: [str(s) for s in v] if v.dtype.kind == "U" else v for k, v in episode.infos.items()}
    return EpisodeBuffer(
        id=index,
        seed=episode.seed,
        observations=episode.observations,
        actions=episode.actions,
        rewards=episode.rewards,
        terminations=episode.terminations,
        truncations=episode.truncations,
        infos=infos,
    )
