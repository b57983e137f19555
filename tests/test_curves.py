"""The learning-curves page (issue 14 point 4): tiny runs of two algorithms from two training
seeds, trained by the command, give a markdown and a self-contained HTML page whose numbers are
those of the runs' validations.csv, with incremental_ik's level on the same validation seeds."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from capture_bench.training.curves.command import main, mean_interval, time_to_baseline

TINY = ["n_envs=2", "total_timesteps=128", "eval_freq=64", "eval_episodes=3",
        "policy_kwargs.net_arch=[8]", "n_steps=32", "checkpoint_freq=0"]  # fmt: skip


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    root = tmp_path_factory.mktemp("curves")
    argv = ["--train", "--algos", "ppo", "a2c", "--seeds", "0", "1",
            "--runs", str(root / "runs"), "--out", str(root / "out")]  # fmt: skip
    argv += [f"--set={item}" for item in TINY]
    assert main(argv) == 0
    return root


def test_the_command_trains_the_runs_and_writes_the_page(page):
    out = page / "out"
    for name in (
        "learning_curves.md",
        "learning_curves.html",
        "learning_curves.png",
        "curves.json",
    ):
        assert (out / name).is_file(), name
    assert {p.name for p in (page / "runs").iterdir()} == {
        "paper-ppo-0", "paper-ppo-1", "paper-a2c-0", "paper-a2c-1"
    }  # fmt: skip
    html = (out / "learning_curves.html").read_text()
    assert "data:image/png;base64," in html and "<table>" in html and 'src="http' not in html
    md = (out / "learning_curves.md").read_text()
    assert "Time to `incremental_ik`" in md and "| PPO |" in md and "| A2C |" in md
    assert "machine" in md


def test_the_numbers_are_the_runs_validations(page):
    numbers = json.loads((page / "out" / "curves.json").read_text())
    rates = []
    for seed in (0, 1):
        with open(page / "runs" / f"paper-ppo-{seed}" / "validations.csv") as handle:
            rows = list(csv.DictReader(handle))
        assert [int(r["step"]) for r in rows] == [64, 128]
        rates.append([float(r["capture_rate"]) for r in rows])
    ppo = numbers["curves"]["ppo"]
    assert ppo["steps"] == [64, 128]
    np.testing.assert_allclose(ppo["capture_rate"]["mean"], np.mean(rates, axis=0))
    assert numbers["validation_episodes"] == 3
    assert 0.0 <= numbers["baseline"]["capture_rate"] <= 1.0


def test_the_rliable_numbers_are_rliables_over_the_runs_training_seeds(page):
    """IQM, optimality gap and mean of each algorithm's final validation mean_score over its
    training seeds, and P(PPO > A2C), equal rliable called directly on those scores."""
    from rliable import library, metrics

    from capture_bench.rliable_stats import AGGREGATES, REPS, SEED, seeded_global_numpy

    numbers = json.loads((page / "out" / "curves.json").read_text())["rliable"]
    assert numbers["unit_of_replication"] == "training seed" and numbers["left_out"] == {}
    finals = {}
    for algo in ("ppo", "a2c"):
        last = []
        for seed in (0, 1):
            with open(page / "runs" / f"paper-{algo}-{seed}" / "validations.csv") as handle:
                last.append([float(list(csv.DictReader(handle))[-1]["mean_score"])])
        finals[algo] = np.array(last)
        assert numbers["algorithms"][algo]["final_scores"] == finals[algo][:, 0].tolist()

        def aggregates(x):
            return np.array([metrics.aggregate_iqm(x), metrics.aggregate_optimality_gap(x, 1.0),
                             metrics.aggregate_mean(x)])  # fmt: skip

        with seeded_global_numpy(SEED):  # np.random.seed(SEED), as rliable's users do
            points, intervals = library.get_interval_estimates(
                {algo: finals[algo]}, aggregates, reps=REPS
            )
        for k, figure in enumerate(AGGREGATES):
            row = numbers["algorithms"][algo][figure]
            assert [row["value"], row["low"], row["high"]] == [
                points[algo][k], intervals[algo][0, k], intervals[algo][1, k]
            ]  # fmt: skip
    with seeded_global_numpy(SEED):
        points, intervals = library.get_interval_estimates(
            {"x,y": (finals["ppo"], finals["a2c"])}, metrics.probability_of_improvement, reps=REPS
        )
    (pair,) = numbers["probability_of_improvement"]
    assert (pair["x"], pair["y"]) == ("ppo", "a2c")
    assert [pair["value"], pair["low"], pair["high"]] == [
        points["x,y"],
        *np.ravel(intervals["x,y"]),
    ]
    md = (page / "out" / "learning_curves.md").read_text()
    assert "Aggregate statistics over training seeds (rliable)" in md and "| PPO | A2C |" in md
    # the performance profiles: rliable's, over the same runs' final scores
    assert "![performance profile](performance_profile.png)" in md
    assert (page / "out" / "performance_profile.png").read_bytes().startswith(b"\x89PNG")
    html = (page / "out" / "learning_curves.html").read_text()
    assert html.count('alt="performance profile" src="data:image/png;base64,') == 1
    profile = numbers["performance_profiles"]["ppo"]
    with seeded_global_numpy(SEED):
        shares, bands = library.create_performance_profile(
            {"ppo": finals["ppo"]}, np.array(profile["taus"]), reps=REPS
        )
    assert profile["share"] == shares["ppo"].tolist()
    assert [profile["low"], profile["high"]] == bands["ppo"].tolist()


def test_an_existing_finished_run_is_kept_and_the_page_regenerates_without_training(page, capsys):
    before = (page / "runs" / "paper-ppo-0" / "metadata.json").read_bytes()
    argv = ["--algos", "ppo", "--seeds", "0", "1", "--runs", str(page / "runs"),
            "--out", str(page / "again")]  # fmt: skip
    assert main(argv) == 0
    assert (page / "runs" / "paper-ppo-0" / "metadata.json").read_bytes() == before
    assert (page / "again" / "learning_curves.md").is_file()


def test_the_interval_and_the_time_to_baseline():
    mean, low, high, n = mean_interval(np.array([0.5, 0.7, 0.6, np.nan]))
    assert n == 3 and mean == pytest.approx(0.6)
    assert high - mean == pytest.approx(4.302653 * 0.1 / np.sqrt(3), rel=1e-5)  # t(0.975, 2)
    assert mean_interval(np.array([np.nan]))[3] == 0

    class C:
        steps = np.array([10, 20, 30])
        wall = np.array([1.0, 2.0, 3.0])
        values = {"capture_rate": np.array([0.2, 0.9, 1.0])}

    assert time_to_baseline(C, 0.9) == (20, 2.0)
    assert time_to_baseline(C, 1.01) is None


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--algos", "dqn"], "invalid choice"),
        (["--seeds", "1000000"], "evaluation seeds"),
        (["--runs", "/nonexistent/runs"], "validations.csv"),
        (["--arms", "ppo-hold", "--train"], "--arms reads runs trained by their own commands"),
        (["--scenario", "paper,papr"], "papr"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, argv, expected):
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and expected in err, err
    assert not (tmp_path / "out" / "learning_curves.md").exists()


def test_the_pixel_arm_trains_on_pixels_beside_the_estimate_fed_arm(tmp_path):
    argv = ["--train", "--algos", "ppo", "--pixels", "--seeds", "0",
            "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out")]  # fmt: skip
    argv += [f"--set={item}" for item in TINY]
    assert main(argv) == 0
    saved = json.loads((tmp_path / "runs" / "paper-ppo-pixels-0" / "config.json").read_text())
    assert saved["config"]["observation_source"] == "pixels"
    assert saved["hyperparameters"]["policy"] == "MultiInputPolicy"
    numbers = json.loads((tmp_path / "out" / "curves.json").read_text())
    assert set(numbers["curves"]) == {"ppo", "ppo-pixels"}
    page = (tmp_path / "out" / "learning_curves.md").read_text()
    assert "| PPO-PIXELS |" in page and "| PPO |" in page


def test_an_algorithm_without_pixel_hyperparameters_is_one_line(tmp_path, capsys):
    argv = ["--algos", "a2c", "--pixels", "--out", str(tmp_path / "out")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "configs/pixels/ppo.yaml" in err, err


def test_a_validation_file_without_the_score_column_scores_0_where_nothing_was_captured(tmp_path):
    """Runs trained before validations recorded mean_score: a validation that captured nothing
    scored 0 on every episode, so its mean score is 0; the others stay unknown (NaN)."""
    from capture_bench.training.curves.command import SCORE, read_curve

    (tmp_path / "config.json").write_text(json.dumps({"hyperparameters": {"eval_episodes": 4}}))
    (tmp_path / "validations.csv").write_text(
        "step,wall_time_s,capture_rate,median_capture_time,median_ratio_to_limit\n"
        "100,1.0,0.0,nan,nan\n"
        "200,2.0,0.5,1.5,1.2\n"
    )
    curve = read_curve(tmp_path, "ppo", 0)
    assert curve.values[SCORE][0] == 0.0 and np.isnan(curve.values[SCORE][1])


def test_arms_of_a_mixture_read_their_runs_against_incremental_ik_pooled_over_its_scenarios(
    tmp_path,
):
    """--scenario paper,grasp --arms: the runs <runs>/paper+grasp-<arm>-<seed> trained by
    train.py on the mixture, read under their own names; incremental_ik's level is its
    validation pooled over both scenarios' first seeds, as the mixture's validation pools."""
    import train
    from capture_bench.training.curves.command import baseline_level

    runs = tmp_path / "runs"
    sets = [f"--set={item}" for item in TINY]
    for arm, extra in (("ppo", []), ("ppo-hold", ["--set=curriculum_hold=0"])):
        for seed in (0, 1):
            run_dir = runs / f"paper+grasp-{arm}-{seed}"
            argv = ["--scenario", "paper,grasp", "--seed", str(seed), "--run-dir", str(run_dir)]
            assert train.main([*argv, *sets, *extra]) == 0
    argv = ["--arms", "ppo", "ppo-hold", "--seeds", "0", "1", "--scenario", "paper,grasp",
            "--runs", str(runs), "--out", str(tmp_path / "out")]  # fmt: skip
    assert main(argv) == 0
    numbers = json.loads((tmp_path / "out" / "curves.json").read_text())
    assert set(numbers["curves"]) == {"ppo", "ppo-hold"}
    assert numbers["validation_episodes"] == 3
    assert numbers["baseline"] == baseline_level("paper,grasp", 3)
    paper, grasp = (baseline_level(name, 3)["capture_rate"] for name in ("paper", "grasp"))
    assert numbers["baseline"]["capture_rate"] == pytest.approx((paper + grasp) / 2)
    page = (tmp_path / "out" / "learning_curves.md").read_text()
    assert "| PPO-HOLD |" in page and "each of paper, grasp (pooled)" in page


def test_arms_read_the_seeds_they_have_and_an_arm_with_none_is_one_line(tmp_path, capsys):
    import shutil

    runs = tmp_path / "runs"
    for name in ("paper-ppo-0", "paper-ppo-1", "paper-ppo-hold-1"):
        (runs / name).mkdir(parents=True)
        (runs / name / "config.json").write_text(
            json.dumps({"hyperparameters": {"eval_episodes": 2}})
        )
        (runs / name / "validations.csv").write_text(
            "step,wall_time_s,capture_rate,median_ratio_to_limit,mean_score\n"
            "100,1.0,0.5,1.5,0.3\n200,2.0,1.0,1.2,0.8\n"
        )
    out = tmp_path / "out"
    argv = ["--arms", "ppo", "ppo-hold", "--seeds", "0", "1", "--runs", str(runs), "--out"]
    assert main([*argv, str(out)]) == 0
    numbers = json.loads((out / "curves.json").read_text())
    assert numbers["curves"]["ppo"]["capture_rate"]["n"] == [2, 2]
    assert numbers["curves"]["ppo-hold"]["capture_rate"]["n"] == [1, 1]
    assert "ppo: 0, 1; ppo-hold: 1" in (out / "learning_curves.md").read_text()
    shutil.rmtree(runs / "paper-ppo-hold-1")
    assert main([*argv, str(tmp_path / "out2")]) == 2
    err = capsys.readouterr().err
    assert "no run of arm 'ppo-hold'" in err and len(err.strip().splitlines()) == 1, err


def test_a_run_that_imitated_first_starts_its_curve_at_the_imitations_rounds(tmp_path):
    """imitation.json's validations are the curve's first points, at the environment steps the
    imitation played; the algorithm's validations follow, shifted by all of them (its step 0,
    the imitation's last policy, stands for the last round); a run without the file is as it
    was recorded."""
    import train
    from capture_bench.training.curves.command import SCORE, read_curve

    run_dir = tmp_path / "run"
    sets = [*TINY, "batch_size=64", "imitate=incremental_ik", "imitation_steps=32", "imitation_rounds=2",
            "imitation_epochs=1"]  # fmt: skip
    argv = [*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]
    assert train.main(argv) == 0
    done = json.loads((run_dir / "imitation.json").read_text())
    first = done["validations"][0]
    assert first["wall_time_s"] <= done["wall_time_s"]
    curve = read_curve(run_dir, "dagger", 0)
    rows = list(csv.DictReader((run_dir / "validations.csv").open()))
    total = done["environment_steps"]
    assert curve.steps.tolist() == [
        first["environment_steps"],
        *(total + int(r["step"]) for r in rows),
    ]
    assert curve.values["capture_rate"][0] == first["capture_rate"]
    assert curve.values[SCORE][1:].tolist() == [float(r["mean_score"]) for r in rows]
    assert curve.wall[0] == first["wall_time_s"]
    (run_dir / "imitation.json").unlink()
    assert read_curve(run_dir, "dagger", 0).steps.tolist() == [int(r["step"]) for r in rows]


def test_a_wall_clock_not_recorded_reads_as_a_dash():
    from capture_bench.training.curves.command import _format_time

    assert _format_time(float("nan")) == "-"
    assert _format_time(30.0) == "30 s" and _format_time(600.0) == "10.0 min"
