"""The golden episodes: what today's environments play on a fixed set of seeds, kept so that a
rewrite of the environments can be held to them (``tests/test_golden_episodes.py``).

    python scripts/golden_episodes.py          # play every case, write the files

Cases (`cases`), each a policy on an environment and its seeds:

* the single env, ``CaptureEnv(reuse_target_side=True)``, on the first two published seeds of
  every shipped scenario (the rendered ones included), under ``incremental_ik`` and a seeded
  random-action policy (`RandomActions`); on ``paper`` also with the photogrammetry and truth
  sources, and with pixels (random actions only: the analytic agents need the estimate);
* the vector env, ``CaptureVectorEnv`` with autoreset off and its training-time target side (the
  batched EKF continuing each recording live), 64 sub-envs on the first 64 validation seeds of
  ``paper``, ``noisy``, ``jitter`` and ``grasp`` under the same two policies, and 16 sub-envs with
  pixels on ``paper``.

Each episode is played by the evaluation's own loops (`run_episode`, `run_episodes`) and kept
as its outcome, failure, steps and the float columns of its `EpisodeRecord`; the first
`SERIES_EPISODES` of a case also step by step (the reset's row, then one row per step): the
observation (with pixels: the state, and the image's mean and CRC-32), the reward and the true
distance. ``tests/data/golden_episodes.npz`` holds the arrays, ``case/field`` for each case;
the ``.json`` beside it the cases, the record's columns and the machine, packages and commit
that played them (`capture_bench.provenance`: floats are equal bit for bit only on a machine
whose `reproduction_key` is the same). Made at a clean commit only.
"""

from __future__ import annotations

import io
import json
import sys
import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

GOLDEN = Path(__file__).resolve().parent.parent / "tests" / "data" / "golden_episodes.npz"
POLICIES = ("incremental_ik", "random")
VECTOR_SCENARIOS = ("paper", "noisy", "jitter", "grasp")
SINGLE_SEEDS = 2  # published seeds per scenario, as the stored suite reference
VECTOR_SEEDS = 64
PIXEL_SEEDS = 16
#: Episodes of a case whose per-step series are kept (its first ones; every episode's record is):
#: all of a vector case's would make the file ~5 MB, float mantissas barely compressing.
SERIES_EPISODES = 16


@dataclass(frozen=True)
class Case:
    """A policy on an environment of a scenario, on given seeds.

    Attributes:
        kind: ``"single"`` (one ``CaptureEnv`` playing the seeds in turn) or ``"vector"`` (one
            ``CaptureVectorEnv`` of ``len(seeds)`` sub-envs playing them together).
        scenario: a shipped scenario's name.
        source: the env's ``observation_source`` (None: the scenario's estimator).
        policy: one of `POLICIES`.
        seeds: the episodes' seeds.
    """

    kind: str
    scenario: str
    source: str | None
    policy: str
    seeds: tuple[int, ...]

    @property
    def name(self) -> str:
        """``kind/scenario/source/policy``, the prefix of the case's arrays."""
        return f"{self.kind}/{self.scenario}/{self.source or 'scenario'}/{self.policy}"


def cases() -> list[Case]:
    """Every golden case, in the order the files hold them."""
    from capture_bench.task.scenarios import list_scenarios, load_scenario

    out = []
    for name in list_scenarios():
        seeds = tuple(load_scenario(name).evaluation_seeds[:SINGLE_SEEDS])
        out += [Case("single", name, None, policy, seeds) for policy in POLICIES]
    published = tuple(load_scenario("paper").evaluation_seeds[:SINGLE_SEEDS])
    for source in ("photogrammetry", "truth"):
        out += [Case("single", "paper", source, policy, published) for policy in POLICIES]
    out.append(Case("single", "paper", "pixels", "random", published))
    for name in VECTOR_SCENARIOS:
        seeds = tuple(load_scenario(name).validation_seeds[:VECTOR_SEEDS])
        out += [Case("vector", name, None, policy, seeds) for policy in POLICIES]
    pixel_seeds = tuple(load_scenario("paper").validation_seeds[:PIXEL_SEEDS])
    out.append(Case("vector", "paper", "pixels", "random", pixel_seeds))
    return out


class RandomActions:
    """Uniform actions in [-1, 1]^3 from a generator seeded with the episode's seed, whatever
    the observation (so it plays pixels too); one instance per episode."""

    batched = False

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        """Nothing to forget between steps."""

    def predict(self, observation: Any, **_: Any) -> tuple[np.ndarray, None]:
        """The next action, (3,) float64."""
        return self.rng.uniform(-1.0, 1.0, 3), None


def _step_row(obs: Any) -> dict[str, Any]:
    """One observation's entries of the per-step series: the vector, or with pixels the state
    and the image's mean and CRC-32."""
    if not isinstance(obs, dict):
        return {"obs": np.asarray(obs)}
    image = np.ascontiguousarray(obs["image"])
    return {
        "obs": np.asarray(obs["state"]),
        "image_mean": float(image.mean()),
        "image_crc": zlib.crc32(image.tobytes()),
    }


class _Series:
    """One episode's per-step series, the reset's row first."""

    def __init__(self, obs: Any, distance: float) -> None:
        self.rows = [_step_row(obs)]
        self.distance = [float(distance)]
        self.reward: list[float] = []

    def add(self, obs: Any, reward: float, distance: float) -> None:
        self.rows.append(_step_row(obs))
        self.distance.append(float(distance))
        self.reward.append(float(reward))


def _recording_single_env(env: Any) -> Any:
    """``env`` wrapped to keep each episode's `_Series` (``.series``, the latest last)."""
    import gymnasium as gym

    class Recorder(gym.Wrapper):
        def __init__(self, env: Any) -> None:
            super().__init__(env)
            self.series: list[_Series] = []

        def reset(self, **kwargs: Any) -> Any:
            obs, info = self.env.reset(**kwargs)
            self.series.append(_Series(obs, info["distance"]))
            return obs, info

        def step(self, action: Any) -> Any:
            obs, reward, terminated, truncated, info = self.env.step(action)
            self.series[-1].add(obs, reward, info["distance"])
            return obs, reward, terminated, truncated, info

    return Recorder(env)


def _recording_vector_env(env: Any) -> Any:
    """A vector env with autoreset off wrapped to keep each sub-env's `_Series` of the
    episode it plays after one full reset (``.series``)."""
    from gymnasium.vector import VectorWrapper

    class Recorder(VectorWrapper):
        def __init__(self, env: Any) -> None:
            super().__init__(env)
            self.series: list[_Series] = []
            self.running = np.zeros(env.num_envs, dtype=bool)

        def reset(self, **kwargs: Any) -> Any:
            obs, info = self.env.reset(**kwargs)
            self.series = [_Series(_row(obs, i), info["distance"][i]) for i in range(self.num_envs)]
            self.running = np.ones(self.num_envs, dtype=bool)
            return obs, info

        def step(self, actions: Any) -> Any:
            obs, rewards, terminated, truncated, info = self.env.step(actions)
            for i in np.flatnonzero(self.running).tolist():
                self.series[i].add(_row(obs, i), rewards[i], info["distance"][i])
            self.running &= ~(terminated | truncated)
            return obs, rewards, terminated, truncated, info

    return Recorder(env)


def _row(obs: Any, i: int) -> Any:
    return {key: value[i] for key, value in obs.items()} if isinstance(obs, dict) else obs[i]


def play(case: Case, seeds: tuple[int, ...] | None = None, live: bool = False) -> dict[str, Any]:
    """The case's episodes on ``seeds`` (default: the case's) as the files hold them, played
    now with the current environments; a single-env case with ``live`` runs ``CaptureEnv``
    without ``reuse_target_side`` (its documented equal: the same episodes)."""
    from gymnasium.vector import AutoresetMode

    from capture_bench.agents import make_agent
    from capture_bench.engine.cache import EpisodeCache
    from capture_bench.envs.capture_env import CaptureEnv
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.evaluation.running.rollout import run_episode, run_episodes

    seeds = case.seeds if seeds is None else seeds
    if case.kind == "single":
        env = _recording_single_env(
            CaptureEnv(
                case.scenario,
                observation_source=case.source,
                reuse_target_side=not live,
                episode_cache=EpisodeCache(),
            )
        )
        records = []
        for seed in seeds:
            agent = RandomActions(seed) if case.policy == "random" else make_agent(case.policy, env)
            record, _ = run_episode(
                env, agent, agent_name=case.policy, scenario=case.scenario, seed=seed
            )
            records.append(record)
    else:
        env = _recording_vector_env(
            CaptureVectorEnv(
                len(seeds),
                case.scenario,
                observation_source=case.source,
                autoreset_mode=AutoresetMode.DISABLED,
            )
        )
        agents: Any = (
            [RandomActions(seed) for seed in seeds]
            if case.policy == "random"
            else make_agent(case.policy, env)
        )
        records = run_episodes(
            env, agents, agent_name=case.policy, scenario=case.scenario, seeds=list(seeds)
        )
    env.close()
    return _arrays(records, env.series[:SERIES_EPISODES])


def record_columns() -> list[str]:
    """The float columns of an `EpisodeRecord` the files keep (its timing columns aside)."""
    from typing import get_type_hints

    from capture_bench.evaluation.running.rollout import TIMING_COLUMNS, EpisodeRecord

    hints = get_type_hints(EpisodeRecord)
    return [name for name, kind in hints.items() if kind is float and name not in TIMING_COLUMNS]


def _arrays(records: list[Any], series: list[_Series]) -> dict[str, Any]:
    """The files' arrays of a case's episodes: per episode ``outcome``, ``failure``, ``steps``,
    ``record`` (E, columns); per row of each episode of ``series`` (the first ones), one after
    the other, ``obs``, ``distance`` (and with pixels ``image_mean``, ``image_crc``); per step
    of the same ``reward``."""
    columns = record_columns()
    rows = [row for one in series for row in one.rows]
    out = {
        "outcome": np.array([r.outcome for r in records]),
        "failure": np.array([r.failure for r in records]),
        "steps": np.array([r.steps for r in records], dtype=np.int64),
        "record": np.array([[getattr(r, c) for c in columns] for r in records], dtype=np.float64),
        "obs": np.stack([row["obs"] for row in rows]),
        "distance": np.array([d for one in series for d in one.distance]),
        "reward": np.array([x for one in series for x in one.reward], dtype=np.float64),
    }
    if "image_mean" in rows[0]:
        out["image_mean"] = np.array([row["image_mean"] for row in rows])
        out["image_crc"] = np.array([row["image_crc"] for row in rows], dtype=np.uint32)
    return out


def first_episodes(arrays: dict[str, Any], count: int) -> dict[str, Any]:
    """A case's arrays (`play`'s or the files') cut to its first ``count`` episodes (at most
    `SERIES_EPISODES`: the per-step series hold no more)."""
    steps = arrays["steps"][:count]
    rows, taken = int(steps.sum()) + count, int(steps.sum())
    per_row = ("obs", "distance", "image_mean", "image_crc")
    out = {}
    for name, value in arrays.items():
        if name in per_row:
            out[name] = value[:rows]
        elif name == "reward":
            out[name] = value[:taken]
        else:
            out[name] = value[:count]
    return out


def load() -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """The ``.json`` and each case's arrays by case name."""
    made = json.loads(GOLDEN.with_suffix(".json").read_text())
    with np.load(GOLDEN) as data:
        arrays: dict[str, dict[str, Any]] = {}
        for key in data.files:
            case, _, name = key.rpartition("/")
            arrays.setdefault(case, {})[name] = data[key]
    return made, arrays


def main(argv: list[str] | None = None) -> int:
    from capture_bench.argparsing import OneLineParser
    from capture_bench.files import atomic_write
    from capture_bench.provenance import git_state, machine, package_versions

    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    parser.parse_args(argv)
    git = git_state()
    if git.get("dirty"):
        parser.error(
            "the working tree has uncommitted changes: make the golden episodes at a clean "
            "commit, so the .json can name the code that played them"
        )
    start = time.perf_counter()
    arrays = {}
    for case in cases():
        for name, value in play(case).items():
            arrays[f"{case.name}/{name}"] = value
    seconds = time.perf_counter() - start
    made = {
        "made_by": "scripts/golden_episodes.py",
        "git": git,
        "machine": machine(),
        "packages": package_versions(),
        "record_columns": record_columns(),
        "cases": [{"name": case.name, **asdict(case)} for case in cases()],
    }
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    atomic_write(GOLDEN, buffer.getvalue())
    atomic_write(GOLDEN.with_suffix(".json"), (json.dumps(made, indent=2) + "\n").encode())
    size = GOLDEN.stat().st_size
    print(
        f"{len(made['cases'])} cases played in {seconds:.0f} s; {GOLDEN.name} {size / 1e6:.2f} MB"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
