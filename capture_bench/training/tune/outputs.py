"""What ``tune.py`` writes to its output directory, each file atomically: ``best.yaml`` (the best
trial's hyper-parameters, for ``train.py --config``), ``trials.csv`` and Optuna's optimisation
history and parameter-importance plots (PNG), from every trial in the study's storage.

Several ``tune.py`` on one study may finish close together: each writes the outputs while it holds
a lock on the output folder (`directory_lock`) and reads the trials
only then, so the files written last are those of the study as it stands when the last one ends.
"""

from __future__ import annotations

import csv
import io
import json
import re
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from capture_bench.files import atomic_write, directory_lock

if TYPE_CHECKING:
    from capture_bench.training.tune.options import Setup

OUTPUT_FILES = ("best.yaml", "trials.csv", "optimization_history.png", "param_importances.png")


def write_outputs(study: Any, setup: Setup) -> None:
    """Write ``best.yaml``, ``trials.csv`` and the two plots to ``setup.output`` (atomically) from
    the study's trials as they stand, holding the folder's lock; print a note for each that
    cannot be written yet."""
    with directory_lock(setup.output):
        _write_outputs(study, setup)


def _write_outputs(study: Any, setup: Setup) -> None:
    import optuna

    out = setup.output
    complete = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    atomic_write(out / "trials.csv", trials_csv(study.get_trials(deepcopy=False)).encode())
    if not complete:
        print("note: no trial has completed yet: best.yaml and the plots are not written")
        return
    ours = [t for t in complete if "hyperparameters" in t.user_attrs]  # not added by hand
    if ours:
        best = max(ours, key=lambda t: t.value)
        atomic_write(out / "best.yaml", best_yaml(best, setup).encode())
        print(f"best: trial {best.number}, objective {best.value:.4f} -> {out / 'best.yaml'}")
    else:
        print("note: no completed trial was run by tune.py (none has its hyper-parameters): "
              "best.yaml is not written")  # fmt: skip
    import matplotlib

    matplotlib.use("Agg", force=True)  # files only, no display
    import matplotlib.pyplot as plt
    from optuna.visualization import matplotlib as plots

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        _save(plt, plots.plot_optimization_history(study), out / "optimization_history.png")
        if not any(t.params != complete[0].params for t in complete):  # also: one trial
            print(
                f"note: parameter importance needs >= 2 completed trials with different "
                f"parameters ({len(complete)} completed): param_importances.png not written"
            )
            return
        _save(plt, plots.plot_param_importances(study), out / "param_importances.png")


def _save(plt: Any, axes: Any, path: Path) -> None:
    figure = axes.figure
    figure.set_size_inches(8, 5)
    figure.tight_layout()
    atomic_write(path, writer=lambda name: figure.savefig(name, format="png", dpi=90))
    plt.close(figure)


def best_yaml(trial: Any, setup: Setup) -> str:
    """The ``trial``'s full hyper-parameters as a YAML file for ``train.py --config``, with a
    header saying where they come from."""
    hp = dict(trial.user_attrs["hyperparameters"])
    hp["checkpoint_freq"] = setup.base["checkpoint_freq"]  # tuning saves none
    attrs = trial.user_attrs
    ratio = attrs.get("median_ratio_to_limit")
    ratio_text = "none (no capture)" if ratio is None else f"{ratio:.4g}"
    algo, scenario = setup.config.algo, setup.scenario.name
    header = [
        f"Best trial of Optuna study {setup.study_name!r} ({redacted(setup.storage)}):",
        f"trial {trial.number}, objective {trial.value:.6g} = validation capture rate "
        f"{attrs.get('capture_rate')} on {attrs.get('eval_episodes')} validation seeds, "
        f"median ratio to the limit {ratio_text}",
        f"(after {trial.user_attrs.get('n_timesteps')} steps; objective_value in "
        "capture_bench/training/tune/trial.py).",
        f"Tuned by: {setup.command} (the study's settings, every trial's)",
        f"Train with: python train.py --algo {algo} --scenario {scenario} --config "
        f"{setup.output / 'best.yaml'}",
        "total_timesteps is the per-trial budget it was tuned at; --total-timesteps trains longer.",
    ]
    text = "".join(f"# {line}\n" for line in header)
    return text + yaml.safe_dump(hp, sort_keys=False)


def trials_csv(trials: list[Any]) -> str:
    """The trials as CSV, with the columns of Optuna's ``study.trials_dataframe()`` (which needs
    pandas): number, value, datetime_start, datetime_complete, duration_s, params_<name>...,
    user_attrs_<name>... (the hyper-parameters as JSON), state."""
    params = sorted({name for t in trials for name in t.params})
    attrs = sorted({name for t in trials for name in t.user_attrs})
    columns = ["number", "value", "datetime_start", "datetime_complete", "duration_s"]
    columns += [f"params_{p}" for p in params] + [f"user_attrs_{a}" for a in attrs] + ["state"]
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    for t in trials:
        duration = t.duration.total_seconds() if t.duration is not None else None
        row: list[Any] = [t.number, t.value, t.datetime_start, t.datetime_complete, duration]
        row += [t.params.get(p) for p in params]
        row += [_cell(t.user_attrs.get(a)) for a in attrs]
        row.append(t.state.name)
        writer.writerow("" if v is None else v for v in row)
    return buffer.getvalue()


def _cell(value: Any) -> Any:
    return json.dumps(value, sort_keys=True) if isinstance(value, (dict, list)) else value


def redacted(url: str) -> str:
    """``url`` without a password (``user:secret@host`` -> ``user:***@host``)."""
    return re.sub(r"//([^:/@]*):[^@/]*@", r"//\1:***@", url)
