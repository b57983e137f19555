"""tune.py: a 2-trial SAC study writes best.yaml (which train.py accepts), trials.csv and the plots;
a second run adds trials to the same study; the objective ranks capture rate first; the median
pruner stops a bad trial; every sample is a valid config; bad input is one line and exit 2."""

from __future__ import annotations

import csv
import itertools
import json
import math
import shutil
import sys
from pathlib import Path

import optuna
import pytest
import yaml

import train
import tune
from capture_bench import __main__ as cli
from capture_bench.task.scenarios import load_scenario
from capture_bench.training.config.hyperparameters import (
    load_hyperparameters,
    validate_hyperparameters,
)
from capture_bench.training.tune.command import open_study, parse_args, prepare
from capture_bench.training.tune.options import TuneConfig
from capture_bench.training.tune.search_spaces import SAMPLERS, Choice, merge, sample
from capture_bench.training.tune.trial import objective_value, report_validation

TINY_SAC = """\
n_envs: 1
total_timesteps: 32
policy_kwargs: {net_arch: [16]}
batch_size: 16
buffer_size: 1000
checkpoint_freq: 0
eval_episodes: 1
"""
KEEP = "net_arch,batch_size,buffer_size"  # sampled otherwise; kept small for a fast test


def tiny_argv(root: Path, out: Path, *extra: str) -> list[str]:
    config = root / "sac.yaml"
    config.write_text(TINY_SAC)
    return [
        "--algo", "sac", "--scenario", "paper", "--config", str(config), "--n-timesteps", "32",
        "--n-evaluations", "2", "--keep", KEEP, "--output", str(out), *extra,
    ]  # fmt: skip


@pytest.fixture(scope="module")
def tuned(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    """A 2-trial study (module scope: one tuning for the tests that read it)."""
    root = tmp_path_factory.mktemp("tune")
    out = root / "out"
    argv = tiny_argv(root, out)
    assert tune.main([*argv, "--trials", "2"]) == 0
    return out, argv


def load(out: Path, name: str = "paper-sac") -> optuna.Study:
    return optuna.load_study(study_name=name, storage=f"sqlite:///{out / 'study.db'}")


def test_tuning_writes_best_yaml_trials_csv_and_plots(tuned):
    out, _ = tuned
    for name in ("best.yaml", "trials.csv", "optimization_history.png", "param_importances.png"):
        assert (out / name).stat().st_size > 0, name
    assert (out / "optimization_history.png").read_bytes()[:4] == b"\x89PNG"
    assert not list(out.glob(".tmp-*"))  # every file was renamed into place
    study = load(out)
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 2
    for trial in study.trials:
        assert set(trial.intermediate_values) == {1, 2}  # one report per validation
        assert trial.value == trial.intermediate_values[2]
        assert {"capture_rate", "median_ratio_to_limit"} <= set(trial.user_attrs)
        hp = trial.user_attrs["hyperparameters"]
        assert hp["policy_kwargs"]["net_arch"] == [16] and hp["batch_size"] == 16  # kept
        assert hp["gamma"] == trial.params["gamma"] and hp["gradient_steps"] == hp["train_freq"]
    rows = list(csv.DictReader((out / "trials.csv").open()))
    assert [row["number"] for row in rows] == ["0", "1"]
    assert {row["state"] for row in rows} == {"COMPLETE"}
    assert float(rows[0]["params_learning_rate"]) == study.trials[0].params["learning_rate"]
    assert json.loads(rows[1]["user_attrs_hyperparameters"])["tau"] == study.trials[1].params["tau"]
    best = (out / "best.yaml").read_text()
    header = [line for line in best.splitlines() if line.startswith("#")]
    assert f"trial {study.best_trial.number}," in header[1] and "capture rate" in header[1]
    assert any("python tune.py --algo sac" in line for line in header)


def test_train_accepts_best_yaml(tuned, tmp_path):
    out, _ = tuned
    best = yaml.safe_load((out / "best.yaml").read_text())
    run_dir = tmp_path / "run"
    argv = ["--algo", "sac", "--config", str(out / "best.yaml"), "--run-dir", str(run_dir)]
    assert train.main([*argv, "--total-timesteps", "16"]) == 0
    trained = json.loads((run_dir / "metadata.json").read_text())["hyperparameters"]
    # the trial's hyper-parameters, nothing layered in: sac.yaml's paper section was in the trial
    assert {**trained, "total_timesteps": best["total_timesteps"]} == best
    assert best["use_sde"] is True and best["curriculum_tolerance"] == 0.02


def test_a_second_run_adds_trials_to_the_same_study(tuned, tmp_path):
    first, argv = tuned
    out = tmp_path / "out"
    shutil.copytree(first, out)
    assert tune.main([*tiny_argv(tmp_path, out), "--trials", "1"]) == 0
    study = load(out)
    assert [t.number for t in study.trials] == [0, 1, 2]
    # the sampler is re-seeded with the trials already stored: no repeat of the first sample
    assert study.trials[2].params != study.trials[0].params
    assert len(list(csv.DictReader((out / "trials.csv").open()))) == 3


def test_a_trial_worse_than_the_median_is_pruned_and_stops_training(tmp_path, capsys):
    out = tmp_path / "out"
    argv = tiny_argv(tmp_path, out, "--n-startup-trials", "1")
    setup = prepare(*parse_args(argv))
    out.mkdir()
    study = open_study(setup)
    # a finished trial that captured everything at both validations: the median to beat
    study.add_trial(optuna.trial.create_trial(value=1.0, intermediate_values={1: 1.0, 2: 1.0}))
    assert tune.main([*argv, "--trials", "1"]) == 0
    trial = load(out).trials[1]
    assert trial.state == optuna.trial.TrialState.PRUNED
    assert set(trial.intermediate_values) == {1}  # stopped at the first validation
    assert capsys.readouterr().out.count("eval at") == 1


def test_the_median_pruner_prunes_a_stub_reporting_bad_values(tmp_path):
    """n_evaluations 2: no warm-up (2 // 3 = 0), as the RL Zoo's n_evaluations // 3."""
    config = TuneConfig(algo="sac", n_evaluations=2, n_startup_trials=1, output=str(tmp_path))
    study = open_study(prepare(config))

    def stub(capture_rate: float):
        def objective(trial: optuna.Trial) -> float:
            result = {"capture_rate": capture_rate, "median_ratio_to_limit": 1.5}
            for step in (1, 2):
                if report_validation(trial, result, step, 10):
                    raise optuna.TrialPruned()
            return objective_value(capture_rate, 1.5, 10)

        return objective

    study.optimize(stub(0.8), n_trials=1)
    study.optimize(stub(0.1), n_trials=1)
    study.optimize(stub(0.9), n_trials=1)
    states = [t.state.name for t in study.trials]
    assert states == ["COMPLETE", "PRUNED", "COMPLETE"]
    assert study.trials[1].intermediate_values == {1: objective_value(0.1, 1.5, 10)}
    assert study.trials[1].user_attrs["capture_rate"] == 0.1


@pytest.mark.parametrize("n", [1, 2, 3, 10, 100])
def test_the_objective_is_lexicographic_capture_rate_then_ratio(n):
    ratios = [0.99, 1.0, 1.0001, 1.2, 2.0, 10.0, 1e9, math.inf, math.nan]
    outcomes = [(k / n, r) for k in range(n + 1) for r in ratios if k or math.isnan(r)]

    def worse_ratio(r: float) -> float:  # what the tie-break compares; no capture is the worst
        return max(r, 1.0) if math.isfinite(r) else math.inf

    for (rate_a, ratio_a), (rate_b, ratio_b) in itertools.product(outcomes, repeat=2):
        a, b = objective_value(rate_a, ratio_a, n), objective_value(rate_b, ratio_b, n)
        if rate_a > rate_b:  # one more captured episode outweighs any ratio
            assert a > b, (rate_a, ratio_a, rate_b, ratio_b)
        elif rate_a == rate_b and worse_ratio(ratio_a) < worse_ratio(ratio_b):
            assert a > b, (rate_a, ratio_a, rate_b, ratio_b)
        elif rate_a == rate_b and worse_ratio(ratio_a) == worse_ratio(ratio_b):
            assert a == b
    assert objective_value(1.0, 1.0, n) == 1.0 and objective_value(0.0, math.nan, n) < 0


@pytest.mark.parametrize("algo", sorted(SAMPLERS))
def test_every_sample_is_a_valid_config(algo):
    """Every choice (and both ends of every range) of the space, and random draws, validate."""
    base, _ = load_hyperparameters(algo)
    space = SAMPLERS[algo]
    widest = max(len(p.space.values) if isinstance(p.space, Choice) else 2 for p in space.values())
    fixed = []
    for i in range(widest):
        params = {}
        for name, param in space.items():
            s = param.space
            ends = s.values if isinstance(s, Choice) else (s.low, s.high)
            params[name] = ends[i % len(ends)]
        fixed.append(optuna.trial.FixedTrial(params))
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for trial in [*fixed, *(study.ask() for _ in range(20))]:
        for budget in (1, 64, 10**6):
            hp = validate_hyperparameters(merge(base, sample(trial, algo, budget)), algo, algo)
            assert hp["learning_rate"] > 0


def test_kept_parameters_are_not_sampled():
    trial = optuna.create_study().ask()
    sampled = sample(trial, "ppo", 1000, keep=("net_arch", "n_steps"))
    assert "n_steps" not in sampled and "policy_kwargs.net_arch" not in sampled
    assert "net_arch" not in trial.params and "batch_size" in trial.params


def one_line_error(capsys, argv: list[str], *expected: str) -> None:
    assert tune.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and err.startswith("tune.py: error: ")
    for text in expected:
        assert text in err, err


def test_bad_input_is_one_line_exit_2_and_overwrites_nothing(capsys, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "best.yaml").write_text("# an earlier result\n")
    base = tiny_argv(tmp_path, out)
    evaluation_seed = str(load_scenario("paper").evaluation_seeds[0])
    validation_count = len(load_scenario("paper").validation_seeds)
    cases = [
        (["--algo", "dqn"], ["dqn", "ppo, a2c, sac, td3, ddpg, tqc"]),
        (["--trials", "-1"], ["--trials", ">= 0"]),
        (["--n-timesteps", "0"], ["--n-timesteps", ">= 1"]),
        (["--n-timesteps", "ten"], ["--n-timesteps", "ten"]),
        (["--n-evaluations", "0"], ["--n-evaluations"]),
        (["--eval-episodes", "0"], ["--eval-episodes"]),
        (["--n-startup-trials", "-2"], ["--n-startup-trials"]),
        (["--n-timesteps", "3", "--n-evaluations", "4"], ["too small", ">= 4"]),
        (["--eval-episodes", str(validation_count + 1)], ["validation seeds", "at most"]),
        (["--seed", evaluation_seed], ["evaluation seeds"]),
        (["--keep", "net_arch,nets"], ["nets", "learning_rate"]),
        (["--vec-env", "ray"], ["batched"]),
        (["--config", str(tmp_path / "missing.yaml")], ["missing.yaml"]),
        (["--output", str(tmp_path / "sac.yaml")], ["--output", "is a file"]),
        (["--storage", "nosuchdb://x/y"], ["--storage", "nosuchdb"]),
    ]
    for extra, expected in cases:
        one_line_error(capsys, [*base, *extra], *expected)
        assert sorted(p.name for p in out.iterdir()) == ["best.yaml"], extra
        assert (out / "best.yaml").read_text() == "# an earlier result\n"


def test_a_study_of_another_algorithm_is_refused(capsys, tmp_path):
    open_study(prepare(TuneConfig(algo="sac", study_name="mine", output=str(tmp_path))))
    one_line_error(
        capsys,
        ["--algo", "td3", "--study-name", "mine", "--output", str(tmp_path)],
        "tunes sac on paper, not td3 on paper",
    )


def test_an_algorithm_without_a_search_space_is_one_line(capsys, monkeypatch, tmp_path):
    monkeypatch.delitem(SAMPLERS, "td3")
    one_line_error(
        capsys,
        ["--algo", "td3", "--output", str(tmp_path)],
        "no search space",
        "ppo, a2c, sac, ddpg, tqc",
    )


def test_without_optuna_it_says_how_to_install_it(capsys, monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "optuna", None)  # `import optuna` raises ImportError
    one_line_error(
        capsys, ["--output", str(tmp_path / "out")], "pip install", "capture-bench[tune]"
    )
    assert not (tmp_path / "out").exists()


def test_python_m_capture_bench_tune_is_the_same_command(capsys):
    assert cli.main(["tune", "--algo", "dqn"]) == 2
    assert "unknown algorithm 'dqn'" in capsys.readouterr().err


def test_ctrl_c_stops_after_writing_what_finished(monkeypatch, tmp_path, capsys):
    """A stand-in for training: trial 0 finishes, Ctrl-C lands in trial 1."""
    from capture_bench.training.tune import trial as tune_trial

    def stand_in(trial: optuna.Trial, setup) -> float:
        settings = tune_trial.trial_hyperparameters(trial, setup)
        trial.set_user_attr("hyperparameters", settings.to_mapping())
        if trial.number == 1:
            raise KeyboardInterrupt
        return 0.5

    monkeypatch.setattr(tune_trial, "run_trial", stand_in)
    out = tmp_path / "out"
    assert tune.main([*tiny_argv(tmp_path, out), "--trials", "5"]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert [t.state.name for t in load(out).trials] == ["COMPLETE", "FAIL"]
    assert "# trial 0, objective 0.5 " in (out / "best.yaml").read_text()
    assert len(list(csv.DictReader((out / "trials.csv").open()))) == 2
    assert (out / "optimization_history.png").is_file()
    assert not (out / "param_importances.png").exists()  # one completed trial: a note instead


# --------------------------------------------------------------------------- a study's settings


def test_a_study_stores_the_settings_that_define_its_trials(tuned):
    out, _ = tuned
    attrs = load(out).user_attrs
    assert attrs["algo"] == "sac" and attrs["scenario"] == "paper"
    assert attrs["n_timesteps"] == 32 and attrs["n_evaluations"] == 2
    assert attrs["eval_episodes"] == 1 and attrs["seed"] == load_scenario("paper").training_seeds[0]
    assert attrs["keep"] == sorted(KEEP.split(","))
    assert attrs["base_hyperparameters"]["buffer_size"] == 1000  # the --config file's
    assert attrs["base_hyperparameters"]["use_sde"] is True  # sac.yaml's paper section
    assert set(attrs["search_space"]) == set(SAMPLERS["sac"]) - set(KEEP.split(","))
    header = (out / "best.yaml").read_text()
    assert "--n-timesteps 32 --n-evaluations 2 --eval-episodes 1" in header


def test_continuing_a_study_without_its_options_runs_its_trials_as_before(
    tuned, tmp_path, capsys, monkeypatch
):
    from capture_bench.training.callbacks import ToleranceCurriculum
    from capture_bench.training.tune import trial as tune_trial

    real, made = tune_trial.curriculum_callbacks, []

    def recording(config, hp):
        made.extend(real(config, hp))
        return list(made)

    monkeypatch.setattr(tune_trial, "curriculum_callbacks", recording)
    first, argv = tuned
    out = tmp_path / "out"
    shutil.copytree(first, out)
    capsys.readouterr()
    plain = ["--algo", "sac", "--scenario", "paper", "--output", str(out), "--trials", "1"]
    assert tune.main(plain) == 0  # sac.yaml alone would train 600000 steps a trial
    printed = capsys.readouterr().out
    assert "note: continuing study 'paper-sac' with its own settings" in printed
    assert "--n-timesteps 32" in printed and "1 more of 32 steps" in printed
    study = load(out)
    added = study.trials[2]
    assert added.user_attrs["n_timesteps"] == 32 and added.user_attrs["eval_episodes"] == 1
    assert added.user_attrs["hyperparameters"]["policy_kwargs"]["net_arch"] == [16]  # kept
    assert set(added.intermediate_values) == {1, 2}
    assert "--n-timesteps 32 --n-evaluations 2" in (out / "best.yaml").read_text()
    # the trial trains as train.py would: sac.yaml's paper section, its curriculum included
    assert [type(c) for c in made] == [ToleranceCurriculum] and made[0].steps == 300_000


def _study_with_a_trial(tmp_path: Path) -> list[str]:
    """A study created by a tiny command, with one finished trial (no training)."""
    out = tmp_path / "out"
    argv = tiny_argv(tmp_path, out)
    setup = prepare(*parse_args(argv))
    out.mkdir()
    open_study(setup).add_trial(optuna.trial.create_trial(value=0.5))
    return argv


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        (["--n-timesteps", "64"], ["--n-timesteps 64", "created with --n-timesteps 32"]),
        (["--n-evaluations", "4"], ["--n-evaluations 4", "created with --n-evaluations 2"]),
        (["--eval-episodes", "3"], ["--eval-episodes 3", "created with --eval-episodes 1"]),
        (["--seed", "5"], ["--seed 5", "created with --seed 0"]),
        (
            ["--keep", "net_arch"],
            ["--keep net_arch", f"created with --keep {','.join(sorted(KEEP.split(',')))}"],
        ),
    ],
)
def test_continuing_a_study_with_another_setting_is_refused_before_any_trial(
    tmp_path, capsys, extra, expected
):
    argv = _study_with_a_trial(tmp_path)
    before = (tmp_path / "out" / "study.db").read_bytes()
    one_line_error(capsys, [*argv, *extra, "--trials", "1"], *expected, "--study-name")
    assert [t.number for t in load(tmp_path / "out").trials] == [0]
    assert (tmp_path / "out" / "study.db").read_bytes() == before


def test_a_config_with_other_hyperparameters_is_refused_naming_the_key(tmp_path, capsys):
    argv = _study_with_a_trial(tmp_path)
    (tmp_path / "sac.yaml").write_text(TINY_SAC.replace("buffer_size: 1000", "buffer_size: 2000"))
    config = str(tmp_path / "sac.yaml")
    (tmp_path / "other.yaml").write_text(TINY_SAC)
    # the same hyper-parameters from another file continue the study
    same = [a if a != config else str(tmp_path / "other.yaml") for a in argv]
    assert tune.main([*same, "--trials", "0"]) == 0
    one_line_error(
        capsys, [*argv, "--trials", "1"], f"--config {config}", "buffer_size 1000, given 2000"
    )


def test_a_changed_search_space_is_refused(tmp_path, capsys, monkeypatch):
    from capture_bench.training.tune.search_spaces import Param

    argv = _study_with_a_trial(tmp_path)
    monkeypatch.setitem(SAMPLERS["sac"], "tau", Param(Choice((0.005, 0.01)), "tau"))
    one_line_error(capsys, [*argv, "--trials", "1"], "samples tau as", "search_spaces.py")


def test_a_study_of_no_trials_takes_the_new_settings(tmp_path):
    out = tmp_path / "out"
    argv = tiny_argv(tmp_path, out)
    out.mkdir()
    open_study(prepare(*parse_args(argv)))  # created, no trial yet
    setup = prepare(*parse_args([*argv, "--n-timesteps", "64"]))
    open_study(setup)
    assert setup.budget == 64 and load(out).user_attrs["n_timesteps"] == 64


def test_a_study_that_stored_no_settings_keeps_what_its_trials_recorded(tmp_path, capsys):
    """A study created before studies stored their settings: its trials' n_timesteps counts."""
    out = tmp_path / "out"
    out.mkdir()
    study = optuna.create_study(
        storage=f"sqlite:///{out / 'study.db'}", study_name="paper-sac", direction="maximize"
    )
    study.set_user_attr("algo", "sac")
    study.set_user_attr("scenario", "paper")
    study.add_trial(
        optuna.trial.create_trial(value=0.5, user_attrs={"n_timesteps": 48, "eval_episodes": 1})
    )
    argv = tiny_argv(tmp_path, out)
    one_line_error(capsys, [*argv, "--trials", "1"], "--n-timesteps 32", "with --n-timesteps 48")
    without = [a for a in argv if a != "32"]
    without.remove("--n-timesteps")
    setup = prepare(*parse_args(without))
    open_study(setup)
    assert setup.budget == 48 and setup.every == 24
    assert load(out).user_attrs["n_timesteps"] == 48  # stored from now on
