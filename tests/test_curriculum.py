"""The tolerance and hold curricula (issue 14 point 1, training only): the training envs count a
capture at a tolerance that shrinks geometrically to the scenario's epsilon, or after a hold that
grows linearly to the scenario's; what is measured (the validation, every evaluation) keeps the
scenario's epsilon and hold."""

from __future__ import annotations

import numpy as np
import pytest
from test_training_metrics import scalars

import train
from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.task.scenarios import load_scenario
from capture_bench.training.callbacks import ToleranceCurriculum

SEED = load_scenario("paper").validation_seeds[2]


def _capture_time(env, seed: int = SEED, agent: str = "incremental_ik") -> float | None:
    """The capture time of ``agent`` on one episode of a single env, s (None: not captured)."""
    controller = make_agent(agent, env)
    obs, _ = env.reset(seed=seed)
    while True:
        obs, _, terminated, truncated, info = env.step(controller.predict(obs)[0])
        if terminated or truncated:
            return info["capture_time"]


def _vector_capture_time(vector, controller, seed: int) -> float | None:
    """The same in a one-sub-env ``CaptureVectorEnv`` (its first episode)."""
    obs, _ = vector.reset(seed=[seed])
    for _ in range(400):
        obs, _, terminated, truncated, info = vector.step(controller.predict(obs)[0])
        if terminated[0] or truncated[0]:
            break
    return info["capture_time"][0]


def test_a_looser_tolerance_captures_earlier_in_both_envs():
    """On the paper's eq. 20 (1 mm, no hold, no speed bound) a looser box captures earlier."""
    exact, loose = CaptureEnv("paper_eq20"), CaptureEnv("paper_eq20")
    try:
        loose.set_capture_tolerance(0.02)
        t_exact, t_loose = _capture_time(exact), _capture_time(loose)
        assert t_exact is not None and t_loose is not None and t_loose < t_exact
        vector = CaptureVectorEnv(1, "paper_eq20")
        vector.set_capture_tolerance(0.02)
        got = _vector_capture_time(vector, make_agent("incremental_ik", exact), SEED)
        assert got == pytest.approx(t_loose, rel=1e-9)
        vector.close()
    finally:
        exact.close()
        loose.close()
    with pytest.raises(ValueError, match="finite and > 0"):
        exact.rule.set_tolerance(-1.0)


def test_the_schedule_is_geometric_from_the_start_to_the_scenarios_epsilon():
    final = np.full(3, 1e-3)
    schedule = ToleranceCurriculum(0.05, final, 1000)
    np.testing.assert_allclose(schedule.tolerance(0), 0.05)
    np.testing.assert_allclose(schedule.tolerance(500), np.sqrt(0.05 * 1e-3))
    np.testing.assert_allclose(schedule.tolerance(1000), final)
    np.testing.assert_allclose(schedule.tolerance(5000), final)


def test_a_run_with_a_curriculum_sets_the_training_tolerance_and_validates_at_epsilon(tmp_path):
    run_dir = tmp_path / "run"
    sets = ["curriculum_tolerance=0.05", "curriculum_steps=96", "n_envs=2", "n_steps=32",
            "batch_size=32", "n_epochs=1", "policy_kwargs.net_arch=[8]", "total_timesteps=128",
            "eval_freq=128", "eval_episodes=2"]  # fmt: skip
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) == 0
    tolerance = [v for _, v in scalars(run_dir / "tb")["train/capture_tolerance_m"]]
    assert tolerance[0] == pytest.approx(0.05) and tolerance == sorted(tolerance, reverse=True)
    assert load_scenario("paper").capture_tolerance <= tolerance[-1] < 0.05 / 2


@pytest.mark.parametrize("key", ["curriculum_steps", "curriculum_delay"])
def test_a_curriculum_schedule_alone_is_one_line(tmp_path, capsys, key):
    argv = ["--set", f"{key}=100", "--run-dir", str(tmp_path / "r")]
    assert train.main(argv) == 2
    err = capsys.readouterr().err
    assert "curriculum_tolerance" in err and "curriculum_hold" in err
    assert len(err.strip().splitlines()) == 1


def test_the_default_curriculum_is_half_the_runs_budget_after_the_options(tmp_path, monkeypatch):
    import json

    from capture_bench.training.common import run as training_run

    monkeypatch.setattr(training_run, "train", lambda *args: 0)  # resolve and save only
    run_dir = tmp_path / "run"
    argv = ["--set", "curriculum_tolerance=0.05", "--total-timesteps", "8192"]
    assert train.main([*argv, "--run-dir", str(run_dir)]) == 0
    hp = json.loads((run_dir / "config.json").read_text())["hyperparameters"]
    assert hp["curriculum_steps"] == 4096  # not half of ppo.yaml's 3,000,000


# -- the hold curriculum ------------------------------------------------------------------------


def _grasp_episode(env, seed: int) -> float | None:
    """The capture time of incremental_ik_uncapped (it flies through the box) on one grasp
    episode, s (None: not captured)."""
    return _capture_time(env, seed, "incremental_ik_uncapped")


def test_a_shorter_hold_captures_at_the_first_entry_and_never_later():
    """The arm's actions do not depend on the hold, so an episode is the same until its first
    capture: with hold 0 the capture is the box's first entry; with the scenario's 0.3 s it is
    an entry + 0.3 s, never earlier, and only episodes that capture with hold 0 can."""
    seeds = load_scenario("grasp").validation_seeds[:6]
    held, flown = CaptureEnv("grasp"), CaptureEnv("grasp")
    try:
        flown.set_capture_hold(0.0)
        pairs = [(_grasp_episode(held, s), _grasp_episode(flown, s)) for s in seeds]
    finally:
        held.close()
        flown.close()
    assert any(t_held is None and t_flown is not None for t_held, t_flown in pairs)
    for t_held, t_flown in pairs:
        if t_held is not None:
            assert t_flown is not None and t_flown <= t_held - 0.3 + 1e-9
    with pytest.raises(ValueError, match="finite and >= 0"):
        held.rule.set_hold(-0.1)


def test_the_vector_env_takes_the_hold_as_the_single_env_does():
    seed = load_scenario("grasp").validation_seeds[0]
    single = CaptureEnv("grasp")
    single.set_capture_hold(0.0)
    vector = CaptureVectorEnv(1, "grasp")
    vector.set_capture_hold(0.0)
    try:
        want = _capture_time(single, seed)  # incremental_ik: it lands, under grasp's v_max
        got = _vector_capture_time(vector, make_agent("incremental_ik", single), seed)
        assert want is not None and got == pytest.approx(want, rel=1e-9)
    finally:
        single.close()
        vector.close()


def test_the_hold_schedule_is_linear_from_the_start_to_the_scenarios_hold():
    from capture_bench.training.callbacks import HoldCurriculum

    schedule = HoldCurriculum(0.0, 0.3, 1000)
    assert [schedule.hold(t) for t in (0, 500, 1000, 5000)] == pytest.approx([0, 0.15, 0.3, 0.3])
    delayed = HoldCurriculum(0.0, 0.3, 1000, delay=300)
    assert [delayed.hold(t) for t in (0, 300, 800, 1300, 9999)] == pytest.approx(
        [0, 0, 0.15, 0.3, 0.3]
    )
    tolerance = ToleranceCurriculum(0.05, np.full(3, 1e-3), 1000, delay=300)
    np.testing.assert_allclose(tolerance.tolerance(300), 0.05)
    np.testing.assert_allclose(tolerance.tolerance(800), np.sqrt(0.05 * 1e-3))


def test_a_run_with_a_hold_curriculum_grows_the_training_hold(tmp_path):
    run_dir = tmp_path / "run"
    sets = ["curriculum_hold=0", "curriculum_steps=96", "curriculum_delay=0", "n_envs=2",
            "n_steps=32", "batch_size=32", "n_epochs=1", "policy_kwargs.net_arch=[8]",
            "total_timesteps=128", "eval_freq=128", "eval_episodes=2"]  # fmt: skip
    argv = ["--scenario", "grasp", *(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]
    assert train.main(argv) == 0
    hold = [v for _, v in scalars(run_dir / "tb")["train/capture_hold_s"]]
    assert hold[0] == 0.0 and hold == sorted(hold) and 0.0 < hold[-1] <= 0.3


@pytest.mark.parametrize(
    ("sets", "expected"),
    [
        (["curriculum_hold=5"], "curriculum_hold 5 s is not below paper's capture.hold 0.3 s"),
        (["curriculum_tolerance=0.0005"], "is not above paper's capture tolerance 0.01 m"),
    ],
)
def test_a_curriculum_that_starts_past_the_scenarios_rule_is_one_line(tmp_path, capsys, sets,
                                                                      expected):  # fmt: skip
    run_dir = tmp_path / "r"
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert expected in err and len(err.strip().splitlines()) == 1, err
    assert not run_dir.exists()


def test_a_curriculum_run_saved_before_curriculum_delay_resumes(tmp_path):
    import json

    run_dir = tmp_path / "run"
    sets = ["curriculum_tolerance=0.05", "n_envs=2", "n_steps=32", "batch_size=32", "n_epochs=1",
            "policy_kwargs.net_arch=[8]", "total_timesteps=64", "checkpoint_freq=64"]  # fmt: skip
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) == 0
    saved = json.loads((run_dir / "config.json").read_text())
    del saved["hyperparameters"]["curriculum_delay"]  # as runs before the key were saved
    (run_dir / "config.json").write_text(json.dumps(saved))
    assert train.main(["--resume", str(run_dir), "--total-timesteps", "128"]) == 0
    assert json.loads((run_dir / "metadata.json").read_text())["total_timesteps"] == 128


def test_the_plain_grasp_command_resolves_to_ppo_yamls_grasp_section():
    """``python train.py --algo ppo --scenario grasp`` reads ppo.yaml's grasp section over its
    top level: the hold and tolerance curricula, the hyper-parameters a PPO run on grasp starts
    from."""
    from pathlib import Path

    import yaml

    from capture_bench.training.config.hyperparameters import resolve_hyperparameters

    hp, _, origin = resolve_hyperparameters("ppo", load_scenario("grasp"), None, ())
    plain, _, _ = resolve_hyperparameters("ppo", load_scenario("paper"), None, ())
    config = Path(__file__).parents[1] / "configs" / "algos" / "ppo.yaml"
    grasp = yaml.safe_load(config.read_text())["grasp"]
    assert origin["section"] == "grasp" and grasp["curriculum_hold"] == 0.0
    assert hp == {**plain, **grasp}
