"""SB3 callbacks of ``train.py``: atomic checkpoints, progress lines and periodic evaluation.

Imports Stable-Baselines3 at module level: import this module only where SB3 is needed.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from capture_bench.task.scenarios import load_scenario
from capture_bench.training.checkpoint import BUFFER_FILE, list_checkpoints, save_checkpoint


class Checkpointer(BaseCallback):
    """Save a checkpoint every ``every`` environment steps (0: only when asked).

    A checkpoint at N steps is the directory ``step_N/`` of :mod:`capture_bench.training.checkpoint`
    (written under a temporary name and renamed, so it is complete when it exists; read back
    without unpickling). Replay buffers older than the last two checkpoints are deleted (they
    are large); the rest of each checkpoint is kept.

    Args:
        directory: where checkpoints go (created).
        every: checkpoint period, environment steps (all envs together).
        replay_buffer: also save the replay buffer.
    """

    def __init__(self, directory: Path, every: int, replay_buffer: bool) -> None:
        super().__init__()
        self.directory = Path(directory)
        self.every = every
        self.replay_buffer = replay_buffer
        self._next = 0

    def _on_training_start(self) -> None:
        if self.every:
            self._next = (self.num_timesteps // self.every + 1) * self.every

    def _on_step(self) -> bool:
        if self.every and self.num_timesteps >= self._next:
            self.save(self.model)
            self._next = (self.num_timesteps // self.every + 1) * self.every
        return True

    def save(self, model: Any) -> Path:
        """Write the checkpoint of ``model`` now; return its directory."""
        path = save_checkpoint(model, self.directory, self.replay_buffer)
        if self.replay_buffer:
            for _, old in list_checkpoints(self.directory)[:-2]:
                (old / BUFFER_FILE).unlink(missing_ok=True)
        return path


class Progress(BaseCallback):
    """Print a progress line about 20 times a run and evaluate every ``eval_freq`` steps.

    Evaluation runs ``eval_episodes`` deterministic episodes on the first of the scenario's
    validation seeds (``Scenario.validation_seeds``: never a published evaluation seed; the same
    seeds every time, for a comparable curve; nothing is learned from them) and logs
    ``eval/capture_rate``, ``eval/mean_reward`` and ``eval/median_capture_time`` (s) to TensorBoard.

    Args:
        config: the run's :class:`~capture_bench.training.options.TrainConfig`.
        hp: its validated hyper-parameters.
        target: total environment steps of the run.
    """

    def __init__(self, config: Any, hp: dict[str, Any], target: int) -> None:
        super().__init__()
        self.config, self.hp, self.target = config, hp, target
        self.print_every = max(min(target // 20, 50_000), 1000)
        self._next_print = 0
        self._next_eval = 0
        self._env: Any = None
        self._clock = time.perf_counter()
        self._clock_steps = 0

    def _on_training_start(self) -> None:
        self._next_print = (self.num_timesteps // self.print_every + 1) * self.print_every
        every = self.hp["eval_freq"]
        self._next_eval = (self.num_timesteps // every + 1) * every if every else 0
        self._clock, self._clock_steps = time.perf_counter(), self.num_timesteps

    def _on_step(self) -> bool:
        if self._next_eval and self.num_timesteps >= self._next_eval:
            self.evaluate()
            every = self.hp["eval_freq"]
            self._next_eval = (self.num_timesteps // every + 1) * every
        if self.num_timesteps >= self._next_print:
            self._print()
            self._next_print = (self.num_timesteps // self.print_every + 1) * self.print_every
        return True

    def _print(self) -> None:
        now = time.perf_counter()
        rate = (self.num_timesteps - self._clock_steps) / max(now - self._clock, 1e-9)
        self._clock, self._clock_steps = now, self.num_timesteps
        episodes: list[dict[str, Any]] = list(self.model.ep_info_buffer or [])
        rewards = [e["r"] for e in episodes]
        successes = list(self.model.ep_success_buffer or [])
        line = f"steps {self.num_timesteps:>9}/{self.target}  {rate:7.0f} steps/s"
        if rewards:
            line += f"  episode reward {np.mean(rewards):7.2f}"
        if successes:
            line += f"  capture rate {np.mean(successes):.2f} (last {len(successes)} episodes)"
        print(line, flush=True)

    def evaluate(self) -> dict[str, float]:
        """Run the evaluation episodes now; log and return their statistics."""
        from capture_bench.envs.capture_env import CaptureEnv

        scenario = load_scenario(self.config.scenario)
        if self._env is None:
            self._env = CaptureEnv(
                scenario,
                observation_source=self.config.observation_source,
                reward=self.hp["reward"],
            )
        stats = self.model.get_vec_normalize_env()
        captures, rewards, times = [], [], []
        for seed in scenario.validation_seeds[: self.hp["eval_episodes"]]:
            obs, _ = self._env.reset(seed=seed)
            total, done, info = 0.0, False, {}
            while not done:
                if stats is not None:
                    obs = stats.normalize_obs(obs)
                action, _ = self.model.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, info = self._env.step(action)
                total += float(reward)
                done = terminated or truncated
            captures.append(bool(info.get("is_success")))
            rewards.append(total)
            if info.get("capture_time") is not None:
                times.append(info["capture_time"])
        result = {
            "capture_rate": float(np.mean(captures)),
            "mean_reward": float(np.mean(rewards)),
            "median_capture_time": float(np.median(times)) if times else float("nan"),
        }
        for key, value in result.items():
            self.logger.record(f"eval/{key}", value)
        print(
            f"eval at {self.num_timesteps} steps on {len(captures)} validation seeds: capture "
            f"rate {result['capture_rate']:.2f}, mean reward {result['mean_reward']:.2f}",
            flush=True,
        )
        return result

    def close(self) -> None:
        """Close the evaluation environment (safe to call twice)."""
        if self._env is not None:
            self._env.close()
            self._env = None
