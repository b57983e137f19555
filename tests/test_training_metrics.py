"""What train.py logs and keeps beside SB3's own: the task's TensorBoard scalars on rollouts (PPO
and SAC) and on the periodic validation, the batched validation (equal to single envs), and the
best model ``best/`` (written atomically, loadable as a policy directory)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from stand_in import sb3_model, spaces

import train
from capture_bench.task.scenarios import load_scenario
from capture_bench.task.step_rule import FAILURES
from capture_bench.training.common.episode_stats import (
    EpisodeStats,
    EpisodeTracker,
    finite_items,
    summarize,
)

METRICS = ("capture_rate", "median_capture_time", "median_ratio_to_limit", "mean_score",
           *(f"failure/{r}" for r in FAILURES), "estimate_position_error_m")  # fmt: skip


def scalars(directory: Path) -> dict[str, list[tuple[int, float]]]:
    """Every scalar of the TensorBoard event files under ``directory``: tag -> [(step, value)]."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(directory.rglob("events.out.tfevents.*")):
        events = EventAccumulator(str(path))
        events.Reload()
        for tag in events.Tags()["scalars"]:
            out.setdefault(tag, []).extend((e.step, e.value) for e in events.Scalars(tag))
    return out


# --------------------------------------------------------------------- rollouts, PPO and SAC

# Scripted episodes, cycled: (length in steps, failure or None for a capture, physical limit, s).
SCRIPT = [(3, None, 0.1), (4, "collision", 1.0), (2, None, math.inf), (5, "timeout", 0.4),
          (3, "target_lost", 0.2), (4, None, 0.15), (2, "unreachable", math.inf)]  # fmt: skip


class Scripted(gymnasium.Env):
    """The benchmark's spaces and the task's ``info`` keys, with scripted episodes (no physics);
    ``ended`` lists (step count, the episode's statistics worked out by hand)."""

    def __init__(self):
        self.observation_space, self.action_space = spaces()
        self.episode, self.t, self.steps = -1, 0, 0
        self.ended: list[tuple[int, EpisodeStats]] = []

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.episode, self.t = self.episode + 1, 0
        return self.observation_space.sample(), {}

    def step(self, action):
        length, failure, limit = SCRIPT[self.episode % len(SCRIPT)]
        self.t, self.steps = self.t + 1, self.steps + 1
        scale = self.episode + 1
        info = {"is_success": False, "failure": None, "capture_time": None,
                "estimate_position_error": NAN if self.t == 1 else 0.01 * self.t * scale}  # fmt: skip
        end = self.t == length
        if end:
            capture_time = 0.05 * length if failure is None else NAN
            info.update(is_success=failure is None, failure=failure, physical_limit_time=limit,
                        capture_time=None if failure else capture_time)  # fmt: skip
            errors = [0.01 * t * scale for t in range(2, length + 1)]
            ratio = capture_time / limit if failure is None and math.isfinite(limit) else NAN
            stats = EpisodeStats(failure is None, failure, capture_time, limit, ratio,
                                 float(np.mean(errors)) if errors else NAN)  # fmt: skip
            self.ended.append((self.steps, stats))
        obs = self.observation_space.sample()
        return obs, 0.0, end and failure != "timeout", end and failure == "timeout", info


NAN = math.nan


@pytest.mark.parametrize("algorithm", ["PPO", "SAC"])
def test_rollout_metrics_cover_the_episodes_ended_since_the_last_write(algorithm, tmp_path):
    """SB3 writes after each rollout (PPO) or every log_interval episodes, in the middle of a
    rollout (SAC); each write holds the statistics of exactly the episodes ended since the last."""
    import stable_baselines3
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import DummyVecEnv

    from capture_bench.training.callbacks import RolloutMetrics

    venv = DummyVecEnv([Scripted])
    kwargs: dict = {"policy_kwargs": {"net_arch": [16]}, "seed": 0, "device": "cpu"}
    if algorithm == "PPO":
        kwargs |= {"n_steps": 16, "batch_size": 16, "n_epochs": 1}
        learn = {"total_timesteps": 96}
    else:
        kwargs |= {"learning_starts": 8, "batch_size": 8, "buffer_size": 200}
        learn = {"total_timesteps": 60, "log_interval": 3}
    model = getattr(stable_baselines3, algorithm)("MlpPolicy", venv, **kwargs)
    model.set_logger(configure(str(tmp_path), ["tensorboard"]))
    model.learn(callback=RolloutMetrics(), **learn)
    logged = scalars(tmp_path)
    writes = [step for step, _ in logged["time/fps"]]  # SB3 writes time/fps at every write
    ended = venv.envs[0].ended
    assert len(writes) >= 3
    checked = 0
    for before, now in zip([0, *writes], writes):
        window = [stats for step, stats in ended if before < step <= now]
        expected = finite_items(summarize(window))
        got = {tag[len("rollout/") :]: dict(values)[now] for tag, values in logged.items()
               if tag.startswith("rollout/") and now in dict(values)}  # fmt: skip
        got = {k: v for k, v in got.items() if k in METRICS}
        assert got == pytest.approx(expected, rel=1e-6), (before, now)
        checked += bool(window)
    assert checked >= 3  # windows with episodes, not only empty ones
    assert {f"rollout/{m}" for m in METRICS} <= set(logged)  # every metric appeared


# --------------------------------------------------------------------- batched validation


def single_env_validation(predictor, seeds, normalize=None):
    """The reference: one plain CaptureEnv episode per seed, one after another."""
    from capture_bench.envs.capture_env import CaptureEnv

    env = CaptureEnv("paper")
    out = []
    try:
        for seed in seeds:
            obs, _ = env.reset(seed=seed)
            tracker, ended = EpisodeTracker(1), []
            while not ended:
                inputs = obs if normalize is None else normalize(obs)
                action, _ = predictor.predict(inputs, deterministic=True)
                obs, reward, terminated, truncated, info = env.step(action)
                ended = tracker.step([info], [terminated or truncated], [reward])
            out.append(ended[0][1])
    finally:
        env.close()
    return out


def assert_same_stats(batched, single):
    assert len(batched) == len(single)
    for a, b in zip(batched, single):
        assert a.captured == b.captured and a.failure == b.failure
        np.testing.assert_allclose(
            [a.capture_time, a.physical_limit_time, a.ratio_to_limit,
             a.estimate_position_error_m, a.reward],
            [b.capture_time, b.physical_limit_time, b.ratio_to_limit,
             b.estimate_position_error_m, b.reward],
            rtol=1e-6, atol=1e-8,  # the batched arithmetic differs in the last bits
        )  # fmt: skip


def test_batched_validation_equals_single_envs_on_the_same_seeds():
    """An analytic controller (captures after different numbers of steps, so sub-envs autoreset
    while others still play) and a small SB3 model with VecNormalize statistics (fails)."""
    from capture_bench.agents.baselines import PurePursuit
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.training.common.validation_run import run_validation

    seeds = list(load_scenario("paper").validation_seeds[:4])
    venv = CaptureVectorEnv(len(seeds), "paper")
    try:
        controller = PurePursuit(venv.description)
        batched = run_validation(controller, venv, seeds)
        assert_same_stats(batched, single_env_validation(controller, seeds))
        assert all(s.captured for s in batched)
        model, vecnormalize = sb3_model("PPO", normalize=True, learn=64)
        batched = run_validation(model, venv, seeds, vecnormalize.normalize_obs)  # env reused
        assert_same_stats(batched, single_env_validation(model, seeds, vecnormalize.normalize_obs))
        assert not any(s.captured for s in batched)
    finally:
        venv.close()


# --------------------------------------------------------------------- a tiny train.py run

TINY = """\
n_envs: 1
total_timesteps: 256
policy_kwargs: {net_arch: [16]}
n_steps: 64
batch_size: 64
n_epochs: 1
checkpoint_freq: 128
eval_freq: 128
eval_episodes: 3
"""


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 256-step PPO run on paper validating every 128 steps (module scope: one training)."""
    root = tmp_path_factory.mktemp("metrics")
    (root / "tiny.yaml").write_text(TINY)
    argv = ["--algo", "ppo", "--scenario", "paper", "--config", str(root / "tiny.yaml")]
    assert train.main([*argv, "--run-dir", str(root / "run"), "--seed", "3"]) == 0
    return root / "run"


def test_tensorboard_holds_the_task_metrics_of_rollouts_and_validation(run_dir):
    logged = scalars(run_dir / "tb")
    rollout = {tag for tag in logged if tag.startswith("rollout/")}
    # every episode so far is a failure: no capture time or ratio to log (NaN is left out)
    assert {"rollout/capture_rate", "rollout/estimate_position_error_m",
            *(f"rollout/failure/{r}" for r in FAILURES)} <= rollout  # fmt: skip
    for tag in ("eval/capture_rate", "eval/mean_reward", "eval/estimate_position_error_m",
                *(f"eval/failure/{r}" for r in FAILURES)):  # fmt: skip
        assert [step for step, _ in logged[tag]] == [128, 256], tag
    rates = [sum(v for t, values in logged.items() if t.startswith("eval/failure/")
                 for s, v in values if s == step) + dict(logged["eval/capture_rate"])[step]
             for step in (128, 256)]  # fmt: skip
    assert rates == pytest.approx([1, 1])  # each episode captured or failed for one reason


def test_best_model_is_written_whole_and_loads_as_a_policy_directory(run_dir):
    import torch

    from capture_bench.agents.sb3_policy import load_sb3_policy
    from capture_bench.envs.capture_env import CaptureEnv
    from capture_bench.evaluation.running.agents_loading import build_agent, resolve_agent
    from capture_bench.training.common.checkpoint import read_checkpoint

    best = run_dir / "best"
    assert sorted(p.name for p in best.iterdir()) == ["metadata.json", "model.zip", "policy.pt",
                                                      "validation.json"]  # fmt: skip
    record = json.loads((best / "validation.json").read_text())
    assert record["step"] == 128  # both validations fail every episode: the first stays (a tie)
    assert record["seeds"] == list(load_scenario("paper").validation_seeds[:3])
    assert {"capture_rate", "mean_reward", "median_capture_time",
            "median_ratio_to_limit"} <= set(record["validation"])  # fmt: skip
    meta = json.loads((best / "metadata.json").read_text())
    final = json.loads((run_dir / "metadata.json").read_text())
    assert meta["total_timesteps"] == 128 and meta["model"] == "model.zip"
    assert set(meta) == set(final) and meta["algorithm"] == "PPO" and meta["scenario"] == "paper"
    # the weights are the policy's at the validation's step (the checkpoint taken then)
    weights = torch.load(best / "policy.pt", weights_only=True)
    at_128 = read_checkpoint(run_dir / "checkpoints" / "step_128").parameters
    for name, tensor in weights.items():
        assert torch.equal(tensor, at_128["state_dicts"]["policy"][name]), name
    assert not list(run_dir.glob(".tmp-*")) and not list(run_dir.glob(".old-*"))

    env = CaptureEnv("paper")
    try:
        policy = load_sb3_policy(best, env)
        obs, _ = env.reset(seed=0)
        assert env.action_space.contains(policy.predict(obs)[0])
        agent = build_agent(resolve_agent(str(best)), env, seed=0)  # as evaluate.py loads it
        np.testing.assert_array_equal(agent.predict(obs)[0], policy.predict(obs)[0])
        trusted = load_sb3_policy(best, env, trust_model=True)  # SB3's best/model.zip too
        np.testing.assert_array_equal(trusted.predict(obs)[0], policy.predict(obs)[0])
    finally:
        env.close()


# --------------------------------------------------------------------- the best-model rule


def test_better_means_capture_rate_then_ratio_to_limit_then_time():
    from capture_bench.training.common.policy_export import is_better

    def v(rate, ratio=NAN, time=NAN):
        return {"capture_rate": rate, "median_ratio_to_limit": ratio, "median_capture_time": time}

    assert is_better(v(0.0), None)
    assert is_better(v(0.6, 3.0), v(0.5, 1.2)) and not is_better(v(0.5, 1.2), v(0.6, 3.0))
    assert is_better(v(0.5, 1.2), v(0.5, 1.3)) and not is_better(v(0.5, 1.3), v(0.5, 1.2))
    assert is_better(v(0.5, 1.2), v(0.5, NAN)) and not is_better(v(0.5, NAN), v(0.5, 1.2))
    assert is_better(v(0.5, NAN, 1.0), v(0.5, NAN, 2.0))
    assert not is_better(v(0.5, 1.2, 1.0), v(0.5, 1.2, 1.0))  # a tie keeps the earlier model
    assert not is_better(v(0.0), v(0.0))


def test_best_dir_is_replaced_only_by_a_better_validation_and_never_half_written(
    tmp_path, monkeypatch
):
    from capture_bench.training.common import policy_export
    from capture_bench.training.common.policy_export import BestModel

    model, _ = sb3_model("PPO", learn=32)
    meta = {"algorithm": "PPO", "scenario": "paper"}
    best = BestModel(tmp_path)
    assert best.offer(model, {"capture_rate": 0.2}, [1, 2], meta)
    assert not best.offer(model, {"capture_rate": 0.1}, [1, 2], meta)
    assert not best.offer(model, {"capture_rate": 0.2}, [1, 2], meta)
    model.num_timesteps = 999
    assert best.offer(model, {"capture_rate": 0.4, "median_ratio_to_limit": NAN}, [1, 2], meta)
    record = json.loads((tmp_path / "best" / "validation.json").read_text())
    assert record["step"] == 999 and record["validation"]["median_ratio_to_limit"] is None

    resumed = BestModel(tmp_path)  # a resumed run beats what the earlier session kept
    assert not resumed.offer(model, {"capture_rate": 0.3}, [1, 2], meta)

    def broken(directory, *args):
        (Path(directory) / "policy.pt").parent.mkdir(parents=True, exist_ok=True)
        (Path(directory) / "policy.pt").write_bytes(b"half")
        raise OSError("disk full")

    monkeypatch.setattr(policy_export, "export_policy", broken)
    with pytest.raises(OSError):
        resumed.offer(model, {"capture_rate": 0.9}, [1, 2], meta)
    record = json.loads((tmp_path / "best" / "validation.json").read_text())
    assert record["step"] == 999 and (tmp_path / "best" / "metadata.json").is_file()
