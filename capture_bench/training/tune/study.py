"""What a tuning study keeps: the settings that define its trials, stored in the Optuna study
(its user attributes) when it is created, so that every trial of a study is trained and validated
the same way and ``best.yaml`` names the command that ran it.

Continuing a study (``tune.py`` again with the same ``--study-name`` and ``--storage``), an option
left out takes the study's value, and an option given with another value is refused, before any
trial runs. A study of no trials yet takes the settings of the command that continues it.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from capture_bench.task.scenarios import ConfigError
from capture_bench.training.tune.search_spaces import describe_space

if TYPE_CHECKING:
    from capture_bench.training.tune.options import Setup

#: The settings that define a trial -> the option that sets each (None: the code, not an option).
#: ``config`` is kept beside them, the path the base hyper-parameters came from (for messages
#: and commands); the hyper-parameters themselves are what must agree.
SETTINGS: dict[str, str | None] = {
    "n_timesteps": "--n-timesteps",
    "n_evaluations": "--n-evaluations",
    "eval_episodes": "--eval-episodes",
    "seed": "--seed",
    "keep": "--keep",
    "base_hyperparameters": "--config",
    "search_space": None,
}
#: The settings each trial records in its own user attributes (studies created before the study
#: stored its settings have only these).
TRIAL_ATTRS = ("n_timesteps", "eval_episodes")


def study_settings(setup: Setup) -> dict[str, Any]:
    """The settings of ``setup`` that define a trial, as plain JSON data (what Optuna stores)."""
    settings = {
        "n_timesteps": setup.budget,
        "n_evaluations": setup.config.n_evaluations,
        "eval_episodes": setup.eval_episodes,
        "seed": setup.config.seed,
        "keep": sorted(setup.keep),
        "base_hyperparameters": setup.base,
        "search_space": describe_space(setup.config.algo, setup.budget, setup.keep),
        "config": setup.config.config,
    }
    return json.loads(json.dumps(settings))


def stored_settings(study: Any) -> dict[str, Any]:
    """The settings ``study`` keeps; for a study that stored none, those its trials recorded."""
    stored = {key: study.user_attrs[key] for key in SETTINGS if key in study.user_attrs}
    if stored:
        stored["config"] = study.user_attrs.get("config")
        return stored
    for trial in study.get_trials(deepcopy=False):
        recorded = {key: trial.user_attrs[key] for key in TRIAL_ATTRS if key in trial.user_attrs}
        if recorded:
            return recorded
    return {}


def keep_settings(study: Any, setup: Setup, given: set[str]) -> None:
    """Make ``setup`` run trials the way ``study``'s others ran, or refuse.

    A setting the study keeps and the command left out takes the study's value (a note says
    which); one given with another value raises. A study of no trials takes the command's
    settings; the study then stores them (also where it stored none before).

    Raises:
        ConfigError: a given option differs from the study's value (the message names the
            option, the study's value and the given one), or the search space of the code does.
    """
    stored = stored_settings(study)
    if study.get_trials(deepcopy=False):
        notes = []
        for key, value in stored.items():
            if key not in SETTINGS:
                continue
            current = study_settings(setup)[key]  # after the adoptions so far (keep: the space)
            if value == current:
                continue
            option = SETTINGS[key]
            if option is None or option.lstrip("-").replace("-", "_") in given:
                raise ConfigError(_refusal(setup, key, value, current, stored.get("config")))
            _adopt(setup, key, value, stored.get("config"))
            notes.append(f"{option} {_shown(key, value, stored.get('config'))}")
        if notes:
            print(f"note: continuing study {setup.study_name!r} with its own settings: "
                  f"{', '.join(notes)}")  # fmt: skip
    settings = study_settings(setup)
    for key in (*SETTINGS, "config"):
        if study.user_attrs.get(key, ...) != settings[key]:
            study.set_user_attr(key, settings[key])


def _adopt(setup: Setup, key: str, value: Any, config: str | None) -> None:
    """Set ``setup``'s setting ``key`` to the study's ``value`` (and what follows from it)."""
    if key == "n_timesteps":
        setup.budget = setup.config.n_timesteps = value
    elif key == "n_evaluations":
        setup.config.n_evaluations = value
    elif key == "eval_episodes":
        setup.eval_episodes = setup.config.eval_episodes = value
    elif key == "seed":
        setup.config.seed = value
    elif key == "keep":
        setup.keep = tuple(value)
        setup.config.keep = ",".join(value) or None
    elif key == "base_hyperparameters":
        setup.base, setup.config.config = value, config
    setup.every = setup.budget // setup.config.n_evaluations


def _shown(key: str, value: Any, config: str | None) -> str:
    if key == "keep":
        return ",".join(value) or "(nothing)"
    if key == "base_hyperparameters":
        return f"(the base hyper-parameters it stored, from {config or 'the shipped file'})"
    return str(value)


def _refusal(setup: Setup, key: str, value: Any, current: Any, config: str | None) -> str:
    """The one line refusing a change of setting ``key`` from the study's ``value``."""
    study = f"study {setup.study_name!r}"
    advice = "choose another --study-name to start a new study"
    if key == "search_space":
        name = next(n for n in sorted({*value, *current}) if value.get(n) != current.get(n))
        return (
            f"{study} samples {name} as {value.get(name, '(not sampled)')}, but "
            f"capture_bench/training/tune/search_spaces.py now samples it as "
            f"{current.get(name, '(not sampled)')}; continue it with the code that created it, "
            f"or {advice}"
        )
    option = SETTINGS[key]
    if key == "base_hyperparameters":
        name = next(k for k in sorted({*value, *current}) if value.get(k) != current.get(k))
        return (
            f"{option} {setup.config.config}: {study} was created over base hyper-parameter "
            f"{name} {value.get(name, '(unset)')}, given {current.get(name, '(unset)')}; "
            f"a study keeps its settings: leave {option} out to continue it, or {advice}"
        )
    return (
        f"{option} {_shown(key, current, config)}: {study} was created with {option} "
        f"{_shown(key, value, config)}; a study keeps its settings: leave {option} out to "
        f"continue it, or {advice}"
    )
