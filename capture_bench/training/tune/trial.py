"""One Optuna trial of ``tune.py``: sample, train on training seeds, validate periodically on
validation seeds, score each validation (`objective_value`), report it and stop where the
pruner says.

Imports Stable-Baselines3 at module level: import this module only where training happens.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import optuna
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger

from capture_bench.training.callbacks import Progress
from capture_bench.training.common.build import (
    build_model,
    build_venv,
    close_envs,
    curriculum_callbacks,
)
from capture_bench.training.config.hyperparameters import CURRICULA
from capture_bench.training.config.options import TrainConfig
from capture_bench.training.config.settings import TrainingSettings
from capture_bench.training.tune.options import Setup
from capture_bench.training.tune.search_spaces import merge, sample


def objective_value(capture_rate: float, ratio: float, n_episodes: int) -> float:
    """The one number Optuna maximises: capture rate first, then the median ratio to the limit.

        score = capture_rate - f(ratio) / (2 n),   f(r) = 1 - 1/max(r, 1) for finite r >= 0,
                                                   f(r) = 1 where r is NaN or infinite,

    with ``n`` the validation episodes. The capture rate moves in steps of 1/n (one episode);
    ``f`` lies in [0, 1] and increases with the ratio, so the tie-break is at most 1/(2n) < 1/n:
    one more captured episode always outranks any ratio, and at equal capture rates a lower ratio
    scores higher (no capture, ratio NaN, gets the worst tie-break).

    Args:
        capture_rate: share of the ``n_episodes`` validation episodes captured, in [0, 1].
        ratio: median over captured episodes of capture time / physical-limit time (>= 1 up to
            tolerance; NaN where none was captured).
        n_episodes: validation episodes (>= 1).
    """
    tie_break = 1.0 - 1.0 / max(ratio, 1.0) if math.isfinite(ratio) else 1.0
    return capture_rate - tie_break / (2 * n_episodes)


def report_validation(trial: Any, result: dict[str, float], step: int, n_episodes: int) -> bool:
    """Report validation ``step`` (1, 2, ...) of ``trial`` to Optuna and keep its raw numbers as
    user attributes (``capture_rate``, ``median_ratio_to_limit``: those of the latest
    validation); return whether the pruner says to stop the trial."""
    ratio = float(result.get("median_ratio_to_limit", float("nan")))
    capture_rate = float(result["capture_rate"])
    trial.report(objective_value(capture_rate, ratio, n_episodes), step)
    trial.set_user_attr("capture_rate", capture_rate)
    trial.set_user_attr("median_ratio_to_limit", ratio if math.isfinite(ratio) else None)
    return bool(trial.should_prune())


class TrialValidation(BaseCallback):
    """Validate every ``every`` environment steps (at most ``n_evaluations`` times) with
    ``progress.evaluate()``, report each to the trial, and stop training when it is pruned.

    Args:
        trial: the Optuna trial.
        progress: the run's `Progress` (its own periodic
            evaluation off); its ``evaluate()`` runs the validation episodes.
        every: environment steps (all envs together) between validations.
        n_evaluations: validations at most.
        n_episodes: validation episodes per validation.
    """

    def __init__(
        self, trial: Any, progress: Any, every: int, n_evaluations: int, n_episodes: int
    ) -> None:
        super().__init__()
        self.trial, self.progress = trial, progress
        self.every, self.n_evaluations, self.n_episodes = every, n_evaluations, n_episodes
        self.validations = 0
        self.pruned = False
        self.score = math.nan  # of the latest validation

    def _on_step(self) -> bool:
        due = (self.validations + 1) * self.every
        if self.validations >= self.n_evaluations or self.num_timesteps < due:
            return True
        self.validations += 1
        result = self.progress.evaluate()
        ratio = result.get("median_ratio_to_limit", float("nan"))
        self.score = objective_value(result["capture_rate"], ratio, self.n_episodes)
        self.pruned = report_validation(self.trial, result, self.validations, self.n_episodes)
        return not self.pruned


def trial_hyperparameters(trial: Any, setup: Setup) -> TrainingSettings:
    """The ``trial``'s sample merged over the base hyper-parameters, with the tuning budget and
    validation schedule, validated like a config file. A curriculum without ``curriculum_steps``
    moves over half the budget, as in ``train.py``."""
    base = {
        **setup.base,
        "total_timesteps": setup.budget,
        "eval_freq": setup.every,
        "eval_episodes": setup.eval_episodes,
        "checkpoint_freq": 0,
    }
    if any(key in base for key in CURRICULA):
        base.setdefault("curriculum_steps", max(1, setup.budget // 2))
    sampled = sample(trial, setup.config.algo, setup.budget, setup.keep)
    source = f"trial {trial.number} of study {setup.study_name!r}"
    return TrainingSettings.from_mapping(merge(base, sampled), setup.config.algo, source)


def run_trial(trial: Any, setup: Setup) -> float:
    """Train and validate one trial; return the score of its last validation.

    Raises:
        optuna.TrialPruned: the median pruner stopped it, or training diverged (SB3 raises
            ValueError on NaN actions, as the Zoo prunes those too).
    """
    settings = trial_hyperparameters(trial, setup)
    for key, value in (
        ("hyperparameters", settings.to_mapping()),
        ("n_timesteps", setup.budget),
        ("eval_episodes", setup.eval_episodes),
    ):
        trial.set_user_attr(key, value)
    config = TrainConfig(
        algo=setup.config.algo,
        scenario=setup.config.scenario,
        total_timesteps=setup.budget,
        n_envs=settings.n_envs,
        vec_env=setup.config.vec_env,
        seed=setup.config.seed,
        observation_source=setup.scenario.estimator.source,
    )
    venv = build_venv(config, settings)
    unvalidated = dataclasses.replace(settings, eval_freq=0)  # TrialValidation validates
    progress = Progress(config, unvalidated, settings.planned_steps())
    validation = TrialValidation(
        trial, progress, setup.every, setup.config.n_evaluations, setup.eval_episodes
    )
    interrupted = False
    try:
        model = build_model(config, settings, venv, tensorboard_log=None)
        # A logger that writes nothing: SB3's default makes an empty folder in the temp
        # directory for every trial.
        model.set_logger(Logger(None, []))
        callbacks = [progress, validation, *curriculum_callbacks(config, settings)]
        model.learn(total_timesteps=setup.budget, callback=callbacks)
    except KeyboardInterrupt:  # Optuna records the trial as failed and re-raises it
        interrupted = True
        raise
    except (AssertionError, ValueError) as exc:
        message = " ".join(str(exc).split())
        trial.set_user_attr("error", message)
        print(f"trial {trial.number}: training failed ({message}); pruned")
        raise optuna.TrialPruned(message) from None
    finally:
        progress.close()
        close_envs(venv, interrupted)
    if validation.pruned:
        raise optuna.TrialPruned(f"pruned after validation {validation.validations}")
    return validation.score
