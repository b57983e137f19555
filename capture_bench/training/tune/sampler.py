"""How ``tune.py`` samples and prunes, the same in every process that runs a study's trials.

Sampler: multivariate TPE, as the RL Zoo's, with the constant liar (a running trial counts as a
bad result, so that concurrent trials do not sample next to one another). Its random numbers for
trial ``n`` come from a generator seeded with ``(--seed, n)`` (`TrialSeededSampler`): the
storage gives each trial of a study its own number, whichever process or machine runs it, so no
two trials share random numbers, concurrent workers and a resumed study included, and a trial
drawn at random (the first ``--n-startup-trials``) draws the same parameters in any process.

Pruner: the median pruner, as the Zoo's: a trial stops at a validation whose score falls below
the median of the completed trials' scores at that validation (no pruning before
``--n-startup-trials`` trials have completed, nor in a trial's first third of validations). It
reads the completed trials from the storage at each validation, so trials running at the same
time in other processes are compared with every trial completed by then.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import optuna
from optuna.samplers import BaseSampler, TPESampler

if TYPE_CHECKING:
    from capture_bench.training.tune.options import TuneConfig


def trial_seed(seed: int, number: int) -> int:
    """The sampler's seed for trial ``number`` of a study tuned with ``--seed seed``: the first
    word of numpy's ``SeedSequence((seed, number))``, so that nearby pairs give unrelated
    streams."""
    return int(np.random.SeedSequence((seed, number)).generate_state(1)[0])


class TrialSeededSampler(BaseSampler):
    """A sampler made afresh for each trial, seeded with `trial_seed` of the trial's number.

    Args:
        make: builds the sampler from a seed (e.g. a seeded `TPESampler`).
        seed: the study's seed (``--seed``).
    """

    def __init__(self, make: Callable[[int], BaseSampler], seed: int) -> None:
        self._make, self._seed = make, seed
        self._sampler = make(trial_seed(seed, 0))

    def before_trial(self, study: optuna.Study, trial: optuna.trial.FrozenTrial) -> None:
        self._sampler = self._make(trial_seed(self._seed, trial.number))
        self._sampler.before_trial(study, trial)

    def infer_relative_search_space(
        self, study: optuna.Study, trial: optuna.trial.FrozenTrial
    ) -> dict[str, Any]:
        return self._sampler.infer_relative_search_space(study, trial)

    def sample_relative(
        self, study: optuna.Study, trial: optuna.trial.FrozenTrial, search_space: dict[str, Any]
    ) -> dict[str, Any]:
        return self._sampler.sample_relative(study, trial, search_space)

    def sample_independent(
        self,
        study: optuna.Study,
        trial: optuna.trial.FrozenTrial,
        param_name: str,
        param_distribution: Any,
    ) -> Any:
        return self._sampler.sample_independent(study, trial, param_name, param_distribution)

    def after_trial(
        self,
        study: optuna.Study,
        trial: optuna.trial.FrozenTrial,
        state: optuna.trial.TrialState,
        values: Sequence[float] | None,
    ) -> None:
        self._sampler.after_trial(study, trial, state, values)

    def reseed_rng(self) -> None:
        self._sampler.reseed_rng()


def configure(study: optuna.Study, config: TuneConfig) -> optuna.Study:
    """Give ``study`` the sampler and pruner of ``config``'s tuning (the module's docstring);
    return it."""

    def tpe(seed: int) -> BaseSampler:
        return TPESampler(
            n_startup_trials=config.n_startup_trials,
            seed=seed,
            multivariate=True,
            constant_liar=True,
        )

    study.sampler = TrialSeededSampler(tpe, config.seed or 0)
    study.pruner = optuna.pruners.MedianPruner(
        n_startup_trials=config.n_startup_trials, n_warmup_steps=config.n_evaluations // 3
    )
    return study
