"""SB3 callbacks of ``train.py``: atomic checkpoints, the task's statistics of the training
episodes, progress lines and periodic validation (which keeps the best model).

TensorBoard scalars written beside SB3's own (the statistics of
`capture_bench.training.common.episode_stats`, NaN ones left out):

* ``rollout/capture_rate``, ``rollout/median_capture_time`` (s), ``rollout/median_ratio_to_limit``,
  ``rollout/mean_score``, ``rollout/failure/<reason>`` (each of ``timeout``, ``collision``,
  ``target_lost``, ``unreachable``), ``rollout/estimate_position_error_m`` (m): over the
  training episodes that ended since the logger last wrote (`RolloutMetrics`; SB3 writes
  after every rollout for PPO and A2C, every ``log_interval`` episodes for SAC and TD3). SB3's
  ``rollout/success_rate`` is instead over the last 100 episodes.
* ``eval/capture_rate``, ``eval/mean_reward``, ``eval/median_capture_time`` (s),
  ``eval/median_ratio_to_limit``, ``eval/mean_score``, ``eval/failure/<reason>``,
  ``eval/estimate_position_error_m`` (m): over the periodic validation's episodes
  (`Progress`).

Imports Stable-Baselines3 at module level: import this module only where SB3 is needed.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from capture_bench.training.common.checkpoint import BUFFER_FILE, list_checkpoints, save_checkpoint
from capture_bench.training.common.episode_stats import (
    EpisodeStats,
    EpisodeTracker,
    finite_items,
    summarize,
)
from capture_bench.training.common.policy_export import (
    BestModel,
    append_validation,
    policy_metadata,
    recorded_wall_time,
)
from capture_bench.training.config.settings import TrainingSettings


def curriculum_progress(step: int, steps: int, delay: int) -> float:
    """How far a curriculum has moved at environment step ``step``: 0 for the first ``delay``
    steps, then linearly to 1 over ``steps`` steps, and 1 after."""
    return min(max(step - delay, 0) / steps, 1.0)


class _Curriculum(BaseCallback):
    """A training-only curriculum: at the start of every rollout (so a resumed run continues
    where it was) the training envs get `value` at the step reached, through their method
    ``ENV_METHOD``, and TensorBoard gets it as ``TAG``. The validation, and everything
    evaluated, keep the scenario's rule; the recorded physical limit stays the scenario's.

    Args:
        start: the starting value (the easy side of the scenario's rule).
        final: the scenario's value.
        steps: environment steps to reach it, once it moves.
        delay: environment steps at ``start`` first.
        indices: the training envs it applies to (None: all; a mixture's curriculum: its
            scenario's share).
        label: the scenario's name where the curriculum is one of a mixture's, appended to
            ``TAG`` (``train/capture_hold_s/grasp``).
    """

    ENV_METHOD = ""
    TAG = ""

    def __init__(  # noqa: PLR0913
        self,
        start: float,
        final: Any,
        steps: int,
        delay: int = 0,
        indices: list[int] | None = None,
        label: str | None = None,
    ) -> None:
        super().__init__()
        self.start, self.final = float(start), np.asarray(final, float)
        self.steps, self.delay = int(steps), int(delay)
        self.indices, self.label = indices, label

    def value(self, step: int) -> Any:
        """The curriculum's value at environment step ``step``."""
        raise NotImplementedError

    def _on_training_start(self) -> None:
        self._on_rollout_start()

    def _on_rollout_start(self) -> None:
        value = self.value(self.num_timesteps)
        self.training_env.env_method(self.ENV_METHOD, value, indices=self.indices)
        tag = self.TAG if self.label is None else f"{self.TAG}/{self.label}"
        self.logger.record(tag, float(np.max(value)))

    def _on_step(self) -> bool:
        return True


class ToleranceCurriculum(_Curriculum):
    """The tolerance curriculum: the training envs count a capture at a tolerance that shrinks
    geometrically from ``start`` (m, each component) to the scenario's epsilon (``final``, m,
    (3,)), eps(t) = start^(1-p) eps^p with p = `curriculum_progress`."""

    ENV_METHOD = "set_capture_tolerance"
    TAG = "train/capture_tolerance_m"

    def value(self, step: int) -> np.ndarray:
        """eps at environment step ``step``, m, (3,)."""
        p = curriculum_progress(step, self.steps, self.delay)
        return self.start ** (1.0 - p) * self.final**p

    tolerance = value


class HoldCurriculum(_Curriculum):
    """The hold curriculum: the training envs ask a capture to hold for a time that grows
    linearly from ``start`` (s; 0: the first entry into the tolerance captures) to the
    scenario's ``capture.hold`` (``final``, s), h(t) = start + (final - start) p with
    p = `curriculum_progress`; ``delay`` gives the policy time to learn to reach the target
    before it must stay."""

    ENV_METHOD = "set_capture_hold"
    TAG = "train/capture_hold_s"

    def value(self, step: int) -> float:
        """The hold at environment step ``step``, s."""
        p = curriculum_progress(step, self.steps, self.delay)
        return float(self.start + (self.final - self.start) * p)

    hold = value


class _Normalized:
    """``model.predict`` on observations normalised first (or not, where ``normalize`` is
    None)."""

    def __init__(self, model: Any, normalize: Any) -> None:
        self.model, self.normalize = model, normalize

    def predict(self, observation: Any, **kwargs: Any) -> Any:
        obs = observation if self.normalize is None else self.normalize(observation)
        return self.model.predict(obs, **kwargs)


class Checkpointer(BaseCallback):
    """Save a checkpoint every ``every`` environment steps (0: only when asked).

    A checkpoint at N steps is the directory ``step_N/`` of
    `capture_bench.training.common.checkpoint` (written under a temporary name and renamed, so it
    is complete when it exists; read back without unpickling). Replay buffers older than the last
    two checkpoints are deleted (they are large); the rest of each checkpoint is kept.

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


class RolloutMetrics(BaseCallback):
    """Log the task's statistics of the training episodes (``rollout/...``, module docstring).

    Each step's ``infos`` and ``dones`` (SB3 passes them for every VecEnv kind) feed an
    `EpisodeTracker`; at each step where episodes end,
    the statistics over every episode ended since the logger last wrote are recorded (the
    recorded values stand until the logger writes them). That the logger has written is seen by
    its recorded values having been cleared, which works whenever SB3 writes: after the rollout
    (on-policy) or in the middle of one, at the step an episode ends (off-policy).
    """

    PREFIX = "rollout/"
    _SENTINEL = "rollout/capture_rate"

    def __init__(self) -> None:
        super().__init__()
        self._tracker: EpisodeTracker | None = None
        self._episodes: list[EpisodeStats] = []

    def _on_training_start(self) -> None:
        self._tracker = EpisodeTracker(self.training_env.num_envs)
        self._episodes = []

    def _on_step(self) -> bool:
        assert self._tracker is not None  # set at training start
        ended = self._tracker.step(self.locals["infos"], self.locals["dones"])
        if ended:
            if self._SENTINEL not in self.logger.name_to_value:  # written since: a new window
                self._episodes = []
            self._episodes.extend(stats for _, stats in ended)
            for key, value in finite_items(summarize(self._episodes)).items():
                self.logger.record(self.PREFIX + key, value)
        return True


class Progress(BaseCallback):
    """Print a progress line about 20 times a run, validate every ``eval_freq`` steps and keep the
    best model.

    Validation plays ``eval_episodes`` deterministic episodes on the first of the scenario's
    validation seeds (``Scenario.validation_seeds``: never a published evaluation seed; the same
    seeds every time, for a comparable curve; nothing is learned from them), one per sub-env of a
    batched [`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv]
    (`run_validation`), and logs ``eval/...`` (module
    docstring) to TensorBoard. A validation better than every earlier one of the run (higher
    capture rate, then lower median ratio to the physical limit:
    `is_better`) writes ``run_dir/best/``
    (`BestModel`).

    Args:
        config: the run's `TrainConfig`.
        settings: its validated hyper-parameters.
        target: total environment steps of the run.
        keep_best: write ``best/`` under ``config.run_dir`` (nothing where it is None).
    """

    def __init__(
        self, config: Any, settings: TrainingSettings, target: int, *, keep_best: bool = True
    ) -> None:
        super().__init__()
        self.config, self.settings, self.target = config, settings, target
        self.print_every = max(min(target // 20, 50_000), 1000)
        self._next_print = 0
        self._next_eval = 0
        self._envs: dict[str, Any] = {}  # scenario name -> its validation env
        self._clock = time.perf_counter()
        self._clock_steps = 0
        self._session_start = time.perf_counter()
        run_dir = getattr(config, "run_dir", None)
        self.run_dir = Path(run_dir) if run_dir else None
        self.best = BestModel(self.run_dir) if keep_best and self.run_dir else None
        self.validate_at_start = False  # also validate before the first step (after imitation)
        self.extra_wall_s = 0.0  # this session's time before learning (the imitation), s

    def _on_training_start(self) -> None:
        self._next_print = (self.num_timesteps // self.print_every + 1) * self.print_every
        every = self.settings.eval_freq
        self._next_eval = (self.num_timesteps // every + 1) * every if every else 0
        self._clock, self._clock_steps = time.perf_counter(), self.num_timesteps
        self._session_start = self._clock
        if self.validate_at_start and every and self.num_timesteps == 0:
            self.evaluate()

    def _on_step(self) -> bool:
        if self._next_eval and self.num_timesteps >= self._next_eval:
            self.evaluate()
            every = self.settings.eval_freq
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

    def play(self, model: Any) -> tuple[dict[str, float], list[int], dict[str, dict[str, float]]]:
        """Play the validation episodes with ``model`` (nothing logged): the pooled statistics
        (`summarize`; each scenario of a mixture
        weighs the same), the seeds, and on a mixture each scenario's own statistics."""
        from capture_bench.envs.vector_env import CaptureVectorEnv
        from capture_bench.training.common.mixture import mixture_scenarios
        from capture_bench.training.common.validation_run import run_validation

        stats = model.get_vec_normalize_env()
        normalize = None if stats is None else stats.normalize_obs
        scenarios = mixture_scenarios(self.config.scenario)  # one, or a mixture's
        episodes, seeds = [], []
        own: dict[str, dict[str, float]] = {}
        for scenario in scenarios:
            chosen = list(scenario.validation_seeds[: self.settings.eval_episodes])
            if scenario.name not in self._envs:
                self._envs[scenario.name] = CaptureVectorEnv(
                    len(chosen),
                    scenario,
                    observation_source=self.config.observation_source,
                    reward=self.settings.reward,
                    **self.settings.pixel_options,
                )
            env = self._envs[scenario.name]
            predictor: Any = model
            scaled = normalize
            if self.settings.residual != "none":  # the base sees the raw observation
                from capture_bench.agents.residual import ResidualAgent, make_base

                learned = _Normalized(model, normalize)
                base = make_base(self.settings.residual, env.description)
                scale = self.settings.residual_scale
                predictor, scaled = ResidualAgent(base, learned, scale), None
            front_end = self.settings.front_end_spec
            if front_end is not None:  # a fresh front end: no pose carried over
                predictor = front_end.agent(model, env, "validation")
            played = run_validation(predictor, env, chosen, scaled)
            if len(scenarios) > 1:
                own[scenario.name] = summarize(played)
            episodes += played
            seeds += chosen
        return summarize(episodes), seeds, own

    def evaluate(self) -> dict[str, float]:
        """Run the validation episodes now; log and return their statistics.

        Returns:
            `summarize`'s statistics of the episodes:
            ``capture_rate``, ``mean_reward``, ``median_capture_time`` (s),
            ``median_ratio_to_limit`` (NaN if nothing captured), ``mean_score``,
            ``failure/<reason>``, ``estimate_position_error_m`` (m).
        """
        result, seeds, own = self.play(self.model)
        for name, stats in own.items():  # a mixture: each scenario's own figures too
            for key in ("capture_rate", "median_ratio_to_limit"):
                if np.isfinite(stats[key]):
                    self.logger.record(f"eval/{name}/{key}", stats[key])
        for key, value in finite_items(result).items():
            self.logger.record(f"eval/{key}", value)
        line = (
            f"eval at {self.num_timesteps} steps on {len(seeds)} validation seeds: capture "
            f"rate {result['capture_rate']:.2f}, mean reward {result['mean_reward']:.2f}"
        )
        if not np.isnan(result["median_ratio_to_limit"]):
            line += f", median ratio to the physical limit {result['median_ratio_to_limit']:.2f}"
        if self.run_dir is not None:
            wall = (
                recorded_wall_time(self.run_dir)
                + self.extra_wall_s
                + time.perf_counter()
                - self._session_start
            )
            append_validation(self.run_dir, self.num_timesteps, wall, result)
            if self.best is not None:
                config, settings = self.config, self.settings
                metadata = policy_metadata(self.model, config, settings, wall, sb3_files=True)
                if self.best.offer(self.model, result, seeds, metadata):
                    line += f"; best so far -> {self.best.directory}"
        print(line, flush=True)
        return result

    def close(self) -> None:
        """Close the evaluation environment (safe to call twice)."""
        for env in self._envs.values():
            env.close()
        self._envs = {}
