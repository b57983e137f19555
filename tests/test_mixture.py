"""Training on a mixture of scenarios (issue 14 point 3): the mixture's transitions are its parts'
side by side, seeded by SB3's rule across the parts; the spec names every or some scenarios."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from capture_bench.task.scenarios import ConfigError, list_scenarios
from capture_bench.training.common.mixture import (
    MixtureVecEnv,
    is_mixture,
    mixture_name,
    mixture_scenarios,
)
from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv
from capture_bench.training.config.settings import TrainingSettings


def test_the_mixture_steps_as_its_parts_side_by_side():
    parts = [CaptureSB3VecEnv(2, "paper", seed=3), CaptureSB3VecEnv(3, "tumbling", seed=3)]
    mix = MixtureVecEnv(
        [CaptureSB3VecEnv(2, "paper", seed=3), CaptureSB3VecEnv(3, "tumbling", seed=3)]
    )
    rng = np.random.default_rng(0)
    try:
        assert mix.num_envs == 5
        mix.seed(11)
        parts[0].seed(11)
        parts[1].seed(13)  # SB3's rule: sub-env i gets seed + i, here i = 2 for tumbling's first
        obs = mix.reset()
        np.testing.assert_array_equal(obs, np.concatenate([p.reset() for p in parts]))
        for _ in range(220):  # past the end of the first episodes
            actions = rng.uniform(-1, 1, (5, 3)).astype(np.float32)
            mix.step_async(actions)
            got = mix.step_wait()
            parts[0].step_async(actions[:2])
            parts[1].step_async(actions[2:])
            want = [p.step_wait() for p in parts]
            for j in range(3):
                np.testing.assert_array_equal(got[j], np.concatenate([w[j] for w in want]))
            assert [i.get("terminal_observation") is None for i in got[3]] == [
                i.get("terminal_observation") is None for w in want for i in w[3]
            ]
        assert mix.get_attr("episode_seed") == [
            s for p in parts for s in p.get_attr("episode_seed")
        ]
        assert mix.get_attr("reward_mode", indices=[4]) == ["dense"]
    finally:
        mix.close()
        for p in parts:
            p.close()


def test_the_spec_names_every_or_some_scenarios():
    analytic = list_scenarios(camera="analytic")  # "all": the analytic camera's ranked ones
    assert [s.name for s in mixture_scenarios("all")] == [n for n in analytic if n != "paper_eq20"]
    assert "paper_rendered" in list_scenarios() and "paper_rendered" not in analytic
    assert [s.name for s in mixture_scenarios("paper, grasp")] == ["paper", "grasp"]
    assert is_mixture("all") and is_mixture("paper,grasp") and not is_mixture("paper")
    assert mixture_name("paper,grasp") == "paper+grasp" and mixture_name("all") == "all"
    with pytest.raises(ConfigError, match="named twice"):
        mixture_scenarios("paper,paper")
    with pytest.raises(ConfigError, match="empty name"):
        mixture_scenarios("paper,")
    with pytest.raises(ConfigError, match="unknown scenario 'moon'"):
        mixture_scenarios("paper,moon")


TINY = ["n_steps=32", "batch_size=32", "n_epochs=1", "policy_kwargs.net_arch=[8]",
        "total_timesteps=128", "eval_freq=128", "eval_episodes=2"]  # fmt: skip


def test_a_tiny_mixture_run_trains_validates_each_scenario_loads_and_resumes(tmp_path, monkeypatch):
    import json

    from test_training_metrics import scalars

    import train
    from capture_bench.agents.sb3_policy import load_sb3_policy
    from capture_bench.envs.capture_env import CaptureEnv

    monkeypatch.chdir(tmp_path)
    argv = ["--scenario", "paper,grasp", "--n-envs", "4", *(f"--set={s}" for s in TINY)]
    assert train.main(argv) == 0
    run_dir = tmp_path / "runs" / "paper+grasp-ppo-0"
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["scenario"] == "paper+grasp" and meta["env_id"] is None
    tags = scalars(run_dir / "tb")
    assert {"eval/paper/capture_rate", "eval/grasp/capture_rate", "eval/capture_rate"} <= set(tags)
    validation = json.loads((run_dir / "best" / "validation.json").read_text())
    assert len(validation["seeds"]) == 4  # 2 validation seeds of each scenario
    for name in ("paper", "grasp"):
        env = CaptureEnv(name)
        try:
            agent = load_sb3_policy(run_dir, env)
            obs, _ = env.reset(seed=0)
            assert env.action_space.contains(agent.predict(obs)[0])
        finally:
            env.close()
    # a mixture's config.json has no single observation source (null); it resumes all the same
    assert json.loads((run_dir / "config.json").read_text())["config"]["observation_source"] is None
    assert train.main(["--resume", str(run_dir), "--total-timesteps", "256"]) == 0
    assert json.loads((run_dir / "metadata.json").read_text())["total_timesteps"] == 256
    resumed = ["--resume", str(run_dir), "--total-timesteps", "512", "--vec-env", "dummy"]
    assert train.main(resumed) == 2  # as a new mixture run would be refused


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--n-envs", "3"], "does not split evenly between 2 scenarios"),
        (["--vec-env", "dummy"], "a mixture trains on --vec-env batched"),
        (["--set", "residual=incremental_ik"], "residual depends on one scenario"),
        (["--set", "curriculum_tolerance=0.0001"], "curriculum_tolerance 0.0001 moves on no"),
        (["--scenario", "paper_eq20,grasp", "--set", "curriculum_hold=0.3"], "(none asks a longer"),
        (["--n-envs", "4", "--set", "mixture_weights={grasp: 9}"], "no sub-env of n_envs 4"),
        (["--set", "mixture_weights={grasp: 0}"], "expected a mapping of names to numbers > 0"),
        (["--set", "mixture_weights=[grasp]"], "expected a mapping of names to numbers > 0"),
        (["--scenario", "paper", "--set", "mixture_weights={grasp: 2}"], "train on a mixture"),
    ],
)
def test_what_a_mixture_cannot_take_is_one_line(tmp_path, capsys, argv, expected):
    import train

    run_dir = tmp_path / "run"
    assert train.main(["--scenario", "paper,grasp", *argv, "--run-dir", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert expected in err and len(err.strip().splitlines()) == 1, err
    assert not run_dir.exists()


def test_a_mixtures_curricula_move_on_each_scenario_they_apply_to():
    """Each scenario of a mixture gets the curricula that move on it, on its own share of the
    sub-envs, to its own rule: the hold only where the scenario asks one (grasp and tumbling,
    not paper_eq20), the tolerance on every scenario to its own epsilon."""
    from capture_bench.training.common.build import mixture_curricula

    scenarios = mixture_scenarios("paper_eq20,grasp,tumbling")
    settings = TrainingSettings(algo="ppo", n_envs=12, total_timesteps=100, curriculum_hold=0.0,
                                curriculum_tolerance=0.05, curriculum_steps=10,
                                curriculum_delay=2)  # fmt: skip
    found = mixture_curricula(settings, scenarios, [4, 4, 4])
    holds = [kw for name, kw in found if name == "HoldCurriculum"]
    assert [(kw["label"], kw["indices"]) for kw in holds] == [
        ("grasp", [4, 5, 6, 7]),
        ("tumbling", [8, 9, 10, 11]),
    ]
    assert holds[0]["final"] == scenarios[1].capture.hold > 0
    tolerances = {kw["label"]: kw for name, kw in found if name == "ToleranceCurriculum"}
    assert list(tolerances) == ["paper_eq20", "grasp", "tumbling"]
    assert tolerances["tumbling"]["indices"] == [8, 9, 10, 11]
    assert all(kw["steps"] == 10 and kw["delay"] == 2 for _, kw in found)


def test_a_mixture_run_with_a_hold_curriculum_grows_grasps_hold_alone(tmp_path):
    """train.py on paper_eq20+grasp with curriculum_hold=0: grasp's training hold grows from 0 (its
    own TensorBoard tag), paper_eq20's rule is left alone, the validation keeps both rules."""
    from test_training_metrics import scalars

    import train

    run_dir = tmp_path / "run"
    sets = [*TINY, "total_timesteps=384", "curriculum_hold=0", "curriculum_steps=256",
            "curriculum_delay=0"]  # fmt: skip
    argv = ["--scenario", "paper_eq20,grasp", "--n-envs", "4", *(f"--set={s}" for s in sets)]
    assert train.main([*argv, "--run-dir", str(run_dir)]) == 0
    tags = scalars(run_dir / "tb")
    hold = [v for _, v in tags["train/capture_hold_s/grasp"]]
    assert hold[0] == 0.0 and hold == sorted(hold) and hold[-1] > 0.0
    assert not any(tag.startswith("train/capture_hold_s/paper_eq20") for tag in tags)


def test_the_weights_split_the_sub_envs_in_proportion_and_sum_to_n_envs():
    """mixture_shares: equal without weights; with weights, in proportion (a scenario left out
    weighs 1), the largest remainders rounded up (ties to the earlier scenario), each >= 1."""
    from capture_bench.training.common.mixture import mixture_shares

    names = ["circular", "drift", "evasive", "grasp", "jitter", "noisy", "paper", "tumbling"]
    assert mixture_shares(64, names) == [8] * 8
    assert mixture_shares(64, names, {"grasp": 7}) == [5, 5, 5, 32, 5, 4, 4, 4]
    assert mixture_shares(64, names, {"grasp": 1}) == [8] * 8
    assert mixture_shares(10, ["paper", "grasp"], {"paper": 1.5, "grasp": 1}) == [6, 4]
    assert mixture_shares(3, ["paper", "grasp"], {"paper": 1}) == [2, 1]  # a tie: the first
    for n_envs in range(8, 70):
        for weight in (0.5, 2.0, 3.3, 7.0):
            try:
                shares = mixture_shares(n_envs, names, {"grasp": weight, "paper": 2})
            except ConfigError:  # a scenario left without a sub-env
                assert n_envs < (8 + weight) / min(weight, 1)
                continue
            assert sum(shares) == n_envs
            exact = [n_envs * w / (8 + weight) for w in (1, 1, 1, weight, 1, 1, 2, 1)]
            assert all(abs(s - e) < 1 for s, e in zip(shares, exact, strict=True))


@pytest.mark.parametrize(
    ("n_envs", "weights", "expected"),
    [
        (6, None, "does not split evenly between 4 scenarios"),
        (4, {"grasp": 9}, "leave scenario 'paper' no sub-env of n_envs 4"),
        (8, {"graps": 2}, "names 'graps', which is not in the mixture"),
    ],
)
def test_shares_that_cannot_be_are_refused(n_envs, weights, expected):
    from capture_bench.training.common.mixture import mixture_shares

    names = ["paper", "grasp", "drift", "noisy"][: 4 if weights is None else 2]
    with pytest.raises(ConfigError, match=expected):
        mixture_shares(n_envs, names, weights)


def test_a_weighted_run_gives_each_scenario_its_share_and_grasps_curriculum_its_own(tmp_path):
    """paper_eq20+grasp weighted 1:2 on 6 sub-envs: paper_eq20's batched env has 2, grasp's 4, and the
    hold curriculum moves grasp's 4 (sub-envs 2-5) alone."""
    from capture_bench.training.common.build import build_venv, curriculum_callbacks
    from capture_bench.training.config.options import TrainConfig
    from capture_bench.training.config.settings import resolve_settings

    settings, _, _ = resolve_settings("ppo", None, None, [
        "n_envs=6", "mixture_weights={grasp: 2}", "curriculum_hold=0", "curriculum_steps=10",
        "curriculum_delay=0"])  # fmt: skip
    config = TrainConfig(algo="ppo", scenario="paper_eq20,grasp", n_envs=6, vec_env="batched")
    venv = build_venv(config, dataclasses.replace(settings, residual="none"))
    try:
        mixture = venv.venv
        assert [part.num_envs for part in mixture.parts] == [2, 4]
        assert [p.venv.scenario.name for p in mixture.parts] == ["paper_eq20", "grasp"]
    finally:
        venv.close()
    (hold,) = curriculum_callbacks(config, settings)
    assert (hold.label, hold.indices) == ("grasp", [2, 3, 4, 5])
