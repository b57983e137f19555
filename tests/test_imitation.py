"""Imitation before reinforcement (capture_bench/training/common/imitation.py): DAgger's labels are the
controller's actions on every visited observation (a mixture's rows each by their scenario's
controller), the fit brings the policy's actions to the controller's, the frozen warm-up leaves
the actor alone while the critic learns, and what imitation cannot take is one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

import train
from capture_bench.agents.residual import make_base
from capture_bench.task.episode import describe_task
from capture_bench.task.scenarios import load_scenario
from capture_bench.training.common.imitation import (
    FrozenActor,
    actor_parameters,
    dagger,
    describe_teacher,
    fit,
    label_weights,
    make_teacher,
    teacher_names,
)
from capture_bench.validation import ConfigError

TINY = ["n_envs=4", "total_timesteps=256", "n_steps=32", "batch_size=64", "eval_freq=128",
        "eval_episodes=2", "checkpoint_freq=0", "policy_kwargs.net_arch=[16]"]  # fmt: skip


def _model(n_envs: int, scenario: str = "paper", algo: str = "ppo", **kwargs):
    from stable_baselines3 import PPO, SAC

    from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

    venv = CaptureSB3VecEnv(n_envs, scenario, seed=0)
    policy_kwargs = {"net_arch": [32, 32], "log_std_init": -2.0}
    if algo == "sac":  # gSDE, as configs/algos/sac.yaml's paper section
        model = SAC("MlpPolicy", venv, learning_starts=32, batch_size=64, use_sde=True, seed=0,
                    policy_kwargs=policy_kwargs, device="cpu", **kwargs)  # fmt: skip
    else:
        model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=2, seed=0,
                    policy_kwargs=policy_kwargs, device="cpu", **kwargs)  # fmt: skip
    return model, venv


def test_a_mixtures_teacher_acts_on_each_share_with_its_scenarios_controller():
    paper, grasp = load_scenario("paper"), load_scenario("grasp")
    assert paper.capture_tolerance != grasp.capture_tolerance  # the descriptions differ
    descriptions = [describe_task(paper), describe_task(grasp)]
    teacher = make_teacher(["incremental_ik"] * 2, descriptions, [2, 3])
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (5, 16)).astype(np.float32)
    own = [make_base("incremental_ik", d) for d in descriptions]
    expected = np.concatenate([own[0].predict(obs[:2])[0], own[1].predict(obs[2:])[0]])
    np.testing.assert_array_equal(teacher(obs), expected)


def test_each_scenario_of_a_mixture_can_have_its_own_teacher():
    """``imitate: {default: A, grasp: B}``: grasp's rows are labelled by B, the others' by A,
    each built from its scenario's description; the two controllers differ on these rows."""
    names = teacher_names(
        {"default": "incremental_ik_uncapped", "grasp": "incremental_ik"}, ["paper", "grasp"]
    )
    assert names == ["incremental_ik_uncapped", "incremental_ik"]
    descriptions = [describe_task(load_scenario(n)) for n in ("paper", "grasp")]
    teacher = make_teacher(names, descriptions, [3, 3])
    from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

    venv = CaptureSB3VecEnv(6, "paper", seed=0)
    try:
        obs = venv.reset()
        for _ in range(60):  # close to the target, where the cap on the last step acts
            obs, _, _, _ = venv.step(make_teacher(["incremental_ik"], descriptions[:1], [6])(obs))
    finally:
        venv.close()
    expected = np.concatenate([
        make_base("incremental_ik_uncapped", descriptions[0]).predict(obs[:3])[0],
        make_base("incremental_ik", descriptions[1]).predict(obs[3:])[0],
    ])  # fmt: skip
    np.testing.assert_array_equal(teacher(obs), expected)
    capped = make_base("incremental_ik", descriptions[0]).predict(obs[:3])[0]
    assert not np.array_equal(capped, expected[:3])
    assert teacher_names("dls", ["paper", "grasp"]) == ["dls", "dls"]
    assert teacher_names({"paper": "dls", "grasp": "dls"}, ["paper", "grasp"]) == ["dls", "dls"]
    assert describe_teacher({"default": "dls", "grasp": "incremental_ik"}) == (
        "dls (grasp: incremental_ik)"
    )


@pytest.mark.parametrize(
    ("mapping", "expected"),
    [
        ({"default": "dls", "tumbling": "dls"}, "'tumbling', which is not a scenario of this run"),
        ({"grasp": "dls"}, "gives scenario 'paper' no controller"),
    ],
)
def test_a_teacher_mapping_that_misses_the_runs_scenarios_is_refused(mapping, expected):
    with pytest.raises(ConfigError, match=expected):
        teacher_names(mapping, ["paper", "grasp"])


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_dagger_labels_with_the_teacher_and_the_fit_brings_the_policy_to_it(algo):
    """After DAgger on paper, the policy's deterministic actions on states neither has seen are
    closer (by half) to incremental_ik's than the untrained policy's were: PPO's mean, and SAC's
    squashed action (the fit's targets scaled to its [-1, 1], its ``predict`` back to the env's
    units)."""
    from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

    model, venv = _model(16, algo=algo)
    teacher = make_teacher(["incremental_ik"], [describe_task(load_scenario("paper"))], [16])
    probe = CaptureSB3VecEnv(16, "paper", seed=7)
    try:
        obs = probe.reset()
        states = []
        for _ in range(40):
            states.append(obs)
            obs, _, _, _ = probe.step(teacher(obs))
        target = np.concatenate([teacher(block) for block in states])  # 16 rows at a time
        states = np.concatenate(states)

        def error() -> float:
            action, _ = model.policy.predict(states, deterministic=True)
            return float(np.mean((action - target) ** 2))

        before = error()
        done = dagger(model, venv, teacher, rounds=2, steps=3200, epochs=20, seed=0,
                      log=lambda line: None)  # fmt: skip
        after = error()
    finally:
        probe.close()
        venv.close()
    assert done["rounds"] == 2 and done["environment_steps"] == 2 * 200 * 16
    assert done["labelled_steps"] == done["environment_steps"]
    assert done["agreement"][0] is None and 0.0 <= done["agreement"][1] <= 1.0
    assert done["fit_mse"][-1] < done["fit_mse"][0]
    assert after < 0.5 * before, (before, after)


def test_the_relative_fit_weighs_a_small_step_as_much_as_a_full_one():
    """With a floor, label_weights * |a - a_T|^2 is the same for the same relative error on a
    full-speed label and on a last step a hundred times smaller (floor well below both), the
    weights average 1, and floor 0 is plain MSE."""
    targets = np.array([[1.0, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.5]], dtype=np.float32)
    assert label_weights(targets, 0.0) is None
    w = label_weights(targets, 1e-4)
    assert w.dtype == np.float32 and np.isclose(w.mean(), 1.0)
    errors = w * np.sum((0.1 * targets) ** 2, axis=1)  # 10 % of each action
    np.testing.assert_allclose(errors, errors[0], rtol=1e-3)
    wide = label_weights(targets, 10.0)  # a floor far above every action: nearly equal weights
    np.testing.assert_allclose(wide, 1.0, rtol=1e-2)


@pytest.mark.parametrize(
    ("lr", "batch_size", "steps"), [(1e-3, 40, 1), (2e-4, 40, 1), (1e-3, 16, 3)]
)
def test_the_fit_takes_adam_steps_of_its_rate_on_minibatches_of_its_size(lr, batch_size, steps):
    """One pass over 40 rows is ceil(40 / batch_size) Adam steps, and Adam's first step moves each
    parameter with a gradient by the learning rate: the action head's bias moves by ``lr`` per
    step at most, and by exactly ``lr`` after one step."""
    import torch

    model, venv = _model(2)
    obs = np.random.default_rng(0).normal(size=(40, 16)).astype(np.float32)
    targets = np.full((40, 3), 0.5, dtype=np.float32)  # far from the initial ~0 actions
    bias = model.policy.action_net.bias.detach().clone()
    calls = []
    step = torch.optim.Adam.step

    def counted(self, *args, **kwargs):
        calls.append(1)
        return step(self, *args, **kwargs)

    try:
        torch.optim.Adam.step = counted
        fit(model.policy, obs, targets, 1, 0, lr=lr, batch_size=batch_size)
    finally:
        torch.optim.Adam.step = step
        venv.close()
    assert len(calls) == steps
    moved = (model.policy.action_net.bias.detach() - bias).abs()
    if steps == 1:
        torch.testing.assert_close(moved, torch.full_like(moved, lr), rtol=1e-3, atol=0)
    assert float(moved.max()) <= steps * lr * 1.001


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_the_warm_up_trains_the_critic_alone(algo):
    """PPO's value head, SAC's Q-networks learn while the actor stays as imitated; the actor
    learns once the warm-up is over."""
    import torch

    model, venv = _model(4, algo=algo)
    critic_net = model.policy.critic if algo == "sac" else model.policy.value_net
    try:
        assert not set(map(id, actor_parameters(model.policy))) & set(
            map(id, critic_net.parameters())
        )
        actor = [p.detach().clone() for p in actor_parameters(model.policy)]
        critic = [p.detach().clone() for p in critic_net.parameters()]
        model.learn(256, callback=FrozenActor(10_000))
        assert all(torch.equal(a, p) for a, p in zip(actor, actor_parameters(model.policy)))
        assert not all(torch.equal(a, p) for a, p in zip(critic, critic_net.parameters()))
        assert all(p.requires_grad for p in actor_parameters(model.policy))  # let go at the end
        model.learn(256, callback=FrozenActor(0), reset_num_timesteps=False)
        assert not all(torch.equal(a, p) for a, p in zip(actor, actor_parameters(model.policy)))
    finally:
        venv.close()


def test_a_run_that_imitates_writes_what_it_did_and_validates_the_imitated_policy_first(tmp_path):
    run_dir = tmp_path / "run"
    sets = [*TINY, "imitate=incremental_ik", "imitation_steps=64", "imitation_rounds=2",
            "imitation_epochs=2", "imitation_warmup=128", "imitation_floor=0.05"]  # fmt: skip
    argv = ["--scenario", "paper,grasp", *(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]
    assert train.main(argv) == 0
    done = json.loads((run_dir / "imitation.json").read_text())
    assert done["rounds"] == 2 and done["environment_steps"] == 2 * 16 * 4
    # the imitation's learning curve: the policy validated after each round (pooled seeds)
    assert [v["environment_steps"] for v in done["validations"]] == [64, 128]
    assert all(0.0 <= v["capture_rate"] <= 1.0 for v in done["validations"])
    rows = [line.split(",") for line in (run_dir / "validations.csv").read_text().split()]
    assert [r[0] for r in rows[1:]] == ["0", "128", "256"]
    assert float(rows[1][1]) >= done["wall_time_s"]  # the step-0 wall-clock counts the imitation
    saved = json.loads((run_dir / "config.json").read_text())["hyperparameters"]
    assert saved["imitate"] == "incremental_ik" and saved["imitation_warmup"] == 128
    assert saved["imitation_floor"] == 0.05
    assert (saved["imitation_lr"], saved["imitation_batch"]) == (1e-3, 1024)  # the defaults


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--algo", "td3", "--set", "imitate=dls"], "fits the policy of ppo, a2c, sac, tqc"),
        (["--set", "imitation_steps=10"], "needs imitate"),
        (["--set", "imitate=dls", "--set", "imitation_floor=-1"], "expected a number in [0, 10]"),
        (["--set", "imitate=dls", "--set", "imitation_lr=0"], "imitation_lr"),
        (["--set", "imitate=dls", "--set", "imitation_batch=0"], "imitation_batch"),
        (
            ["--set", "imitate=dls", "--set", "imitation_state_weight=1"],
            "is for a pixel student of ppo or a2c",
        ),
        (["--set", "imitate=oracle"], "expected one of incremental_ik"),
        (["--set", "imitate={paper: oracle}"], "or a mapping of scenario names (and default)"),
        (["--set", "imitate={grasp: dls}"], "'grasp', which is not a scenario of this run"),
        (["--set", "imitate=dls", "--set", "residual=dls"], "choose one"),
        (["--set", "imitate=dls", "--set", "normalize=true"], "set normalize: false"),
        (
            [
                "--set",
                "imitate=dls",
                "--observation-source",
                "pixels",
                "--config",
                "configs/pixels/ppo.yaml",
                "--vec-env",
                "dummy",
            ],
            "use --vec-env batched, not dummy",
        ),
    ],
)
def test_what_imitation_cannot_take_is_one_line(tmp_path, capsys, argv, expected):
    run_dir = tmp_path / "run"
    assert train.main([*argv, "--run-dir", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert expected in err and len(err.strip().splitlines()) == 1, err
    assert not run_dir.exists()


def test_a_run_resumed_inside_its_warm_up_keeps_the_actor_frozen_and_does_not_imitate_again(
    tmp_path,
):
    import torch

    run_dir = tmp_path / "run"
    sets = [*TINY, "checkpoint_freq=128", "imitate=incremental_ik", "imitation_steps=64",
            "imitation_rounds=1", "imitation_epochs=2", "imitation_warmup=100000"]  # fmt: skip
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) == 0
    first = torch.load(run_dir / "policy.pt", weights_only=True)
    (run_dir / "imitation.json").unlink()
    assert train.main(["--resume", str(run_dir), "--total-timesteps", "512"]) == 0
    assert not (run_dir / "imitation.json").exists()  # the checkpoint holds the imitated policy
    second = torch.load(run_dir / "policy.pt", weights_only=True)
    actor = [k for k in first if not k.startswith(("mlp_extractor.value_net", "value_net"))]
    critic = [k for k in first if k.startswith(("mlp_extractor.value_net", "value_net"))]
    assert actor and all(torch.equal(first[k], second[k]) for k in actor)
    assert not all(torch.equal(first[k], second[k]) for k in critic)


def test_a_run_stopped_during_its_imitation_saves_no_checkpoint_and_resumes_from_the_start(
    tmp_path, monkeypatch, capsys
):
    from capture_bench.training.common import imitation

    run_dir = tmp_path / "run"
    sets = [*TINY, "imitate=incremental_ik", "imitation_steps=64", "imitation_rounds=1",
            "imitation_epochs=1"]  # fmt: skip
    real = imitation.dagger

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(imitation, "dagger", stopped)
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) != 0
    assert "interrupted during the imitation" in capsys.readouterr().out
    assert not list((run_dir / "checkpoints").glob("step_*"))
    assert not (run_dir / "imitation.json").exists()
    monkeypatch.setattr(imitation, "dagger", real)
    assert train.main(["--resume", str(run_dir)]) == 0
    assert json.loads((run_dir / "imitation.json").read_text())["rounds"] == 1
    assert (run_dir / "policy.pt").is_file()


def test_the_card_of_an_imitated_policy_says_what_it_imitated_and_counts_every_step(tmp_path):
    from capture_bench.training.train.model_card import ship

    run_dir = tmp_path / "run"
    sets = [*TINY, "imitate=incremental_ik_uncapped", "imitation_steps=64",
            "imitation_rounds=2", "imitation_epochs=1", "imitation_warmup=1000"]  # fmt: skip
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) == 0
    target = ship(run_dir, "tiny", episodes=2, out=tmp_path / "models")
    card = json.loads((target / "metadata.json").read_text())["model_card"]
    assert card["imitation"]["teacher"] == "incremental_ik_uncapped"
    assert card["imitation"]["environment_steps"] == 2 * 16 * 4
    readme = (target / "README.md").read_text()
    assert "started by imitating `incremental_ik_uncapped`" in readme
    assert f"environment steps: {256 + 128:,} (256 of them the algorithm's)" in readme
    assert "the critic alone learned: the policy is the imitation's" in readme


def test_planned_intercept_teaches_with_a_plan_per_training_env_and_captures_when_followed():
    """``imitate: planned_intercept`` is a teacher (not a residual base): following its labels on
    training envs, each row's plan kept between the calls as that env's episodes come, captures
    under the envelope, as the agent does when it plays an episode itself."""
    from capture_bench.agents.residual import RESIDUAL_BASES, TEACHERS
    from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

    assert "planned_intercept" in TEACHERS and "planned_intercept" not in RESIDUAL_BASES
    teacher = make_teacher(["planned_intercept"], [describe_task(load_scenario("paper"))], [4])
    venv = CaptureSB3VecEnv(4, "paper", seed=0)
    captured = ended = 0
    try:
        obs = venv.reset()
        while ended < 8:
            obs, _, dones, infos = venv.step(teacher(obs))
            for done, info in zip(dones, infos, strict=True):
                if done:
                    ended += 1
                    captured += bool(info["is_success"])
    finally:
        venv.close()
    assert captured == ended, f"{captured} of {ended} captured"


# -- a pixel student: the teacher reads the estimate of the step the student sees --------------
PIXEL_SIZE = 36


def test_the_pixel_envs_estimate_observation_is_the_estimate_envs_observation():
    from capture_bench.envs.vector_env import CaptureVectorEnv

    pixels = CaptureVectorEnv(2, "paper", observation_source="pixels", image_size=(36, 36))
    estimate = CaptureVectorEnv(2, "paper")
    try:
        _, _ = pixels.reset(seed=[3, 4])
        obs, _ = estimate.reset(seed=[3, 4])
        for action in np.random.default_rng(0).uniform(-1, 1, (30, 2, 3)):
            np.testing.assert_array_equal(pixels.estimate_observation(), obs)
            pixels.step(action)
            obs, *_ = estimate.step(action)
    finally:
        pixels.close()
        estimate.close()


def _pixel_model(n_envs: int):
    from stable_baselines3 import PPO

    from capture_bench.agents.features import FEATURE_EXTRACTORS
    from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

    venv = CaptureSB3VecEnv(n_envs, "paper", seed=0, observation_source="pixels",
                            image_size=(PIXEL_SIZE,) * 2, frame_stack=2)  # fmt: skip
    policy_kwargs = {"net_arch": [16], "features_extractor_class": FEATURE_EXTRACTORS["combined"]}
    model = PPO("MultiInputPolicy", venv, n_steps=32, batch_size=32, n_epochs=1, seed=0,
                policy_kwargs=policy_kwargs, device="cpu")  # fmt: skip
    return model, venv


def test_dagger_with_a_pixel_student_labels_each_step_with_the_teacher_on_its_estimate(
    monkeypatch,
):
    """Round 0 (the teacher acts) on the same training seeds: the pixel run's labels are the
    estimate-fed run's, action for action; the student is fitted on the images and states."""
    teacher = make_teacher(["incremental_ik"], [describe_task(load_scenario("paper"))], [2])
    labels: dict[str, list[np.ndarray]] = {"pixels": [], "estimate": []}
    seen: list[dict[str, np.ndarray]] = []

    def recording(kind: str):
        def act(observations: np.ndarray) -> np.ndarray:
            assert observations.shape == (2, 16)
            labels[kind].append(teacher(observations))
            return labels[kind][-1]

        return act

    from capture_bench.training.common import imitation

    pixel_model, pixel_venv = _pixel_model(2)
    model, venv = _model(2)
    raw_fit = imitation.fit

    def spying_fit(policy, observations, *args, **kwargs):
        seen.append(observations)
        return raw_fit(policy, observations, *args, **kwargs)

    def view(_obs):
        return pixel_venv.env_method("estimate_observation", indices=[0])[0]

    monkeypatch.setattr(imitation, "fit", spying_fit)
    try:
        done = dagger(pixel_model, pixel_venv, recording("pixels"), rounds=1, steps=80, epochs=2,
                      seed=0, log=lambda line: None, teacher_view=view)  # fmt: skip
        dagger(model, venv, recording("estimate"), rounds=1, steps=80, epochs=1, seed=0,
               log=lambda line: None)  # fmt: skip
    finally:
        pixel_venv.close()
        venv.close()
    assert done["labelled_steps"] == 80 and np.isfinite(done["fit_mse"][0])
    np.testing.assert_array_equal(
        np.concatenate(labels["pixels"]), np.concatenate(labels["estimate"])
    )
    images = seen[0]["image"]
    assert images.dtype == np.uint8 and images.shape == (80, 6, PIXEL_SIZE, PIXEL_SIZE)
    assert seen[0]["state"].shape == (80, 7)


def test_a_pixel_run_imitates_its_teacher_through_train_py(tmp_path):
    run_dir = tmp_path / "run"
    sets = ["n_envs=2", "total_timesteps=64", "n_steps=32", "batch_size=32", "n_epochs=1",
            "policy_kwargs.net_arch=[8]", f"image_size={PIXEL_SIZE}", "frame_stack=2",
            "eval_freq=0", "checkpoint_freq=0", "imitate=incremental_ik", "imitation_steps=32",
            "imitation_rounds=2", "imitation_epochs=1", "imitation_state_weight=0.5"]  # fmt: skip
    argv = ["--observation-source", "pixels", "--config", "configs/pixels/ppo.yaml"]
    argv += [*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]
    assert train.main(argv) == 0
    done = json.loads((run_dir / "imitation.json").read_text())
    assert done["rounds"] == 2 and done["labelled_steps"] == 64
    assert done["agreement"][0] is None and 0.0 <= done["agreement"][1] <= 1.0
    assert len(done["state_mse"]) == 2 and all(np.isfinite(done["state_mse"]))
    saved = json.loads((run_dir / "config.json").read_text())["hyperparameters"]
    assert saved["imitation_state_weight"] == 0.5


def test_the_fits_state_regression_teaches_the_features_what_the_teacher_reads(monkeypatch):
    """With ``state_weight`` the fit also regresses the teacher's (estimate-fed) observation of
    each row from the actor's features: the head learns it, its gradient reaches the features
    extractor, and the policy keeps its own parameters (the head is not one of them)."""
    import torch

    from capture_bench.training.common import imitation

    model, venv = _pixel_model(2)
    teacher = make_teacher(["incremental_ik"], [describe_task(load_scenario("paper"))], [2])
    passed = []
    raw_fit = imitation.fit

    def spying_fit(policy, observations, targets, *args, **kwargs):
        passed.append((observations, targets, args))
        return raw_fit(policy, observations, targets, *args, **kwargs)

    def view(_obs):
        return venv.env_method("estimate_observation", indices=[0])[0]

    monkeypatch.setattr(imitation, "fit", spying_fit)
    keys = set(model.policy.state_dict())
    try:
        dagger(model, venv, teacher, rounds=1, steps=64, epochs=1, seed=0,
               log=lambda line: None, teacher_view=view, state_weight=1.0)  # fmt: skip
    finally:
        venv.close()
    observations, targets, (epochs, seed, floor, lr, batch, state, _marks) = passed[0]
    assert state.weight == 1.0 and state.targets.shape == (64, 16)
    live = state.targets.std(axis=0) > 0
    np.testing.assert_allclose(
        state.targets[:, live].mean(axis=0, dtype=np.float64), 0.0, atol=1e-6
    )
    np.testing.assert_allclose(state.targets[:, live].std(axis=0), 1.0, atol=1e-4)
    assert set(model.policy.state_dict()) == keys
    assert not {id(p) for p in state.head.parameters()} & {id(p) for p in model.policy.parameters()}

    def said_error() -> float:
        with torch.no_grad():
            obs, _ = model.policy.obs_to_tensor(observations)
            _, said = imitation._actions_and_state(model.policy, obs, state.head)
            return float(torch.mean((said - torch.as_tensor(state.targets)) ** 2))

    extractor = model.policy.pi_features_extractor
    before, start = said_error(), [p.detach().clone() for p in extractor.parameters()]
    raw_fit(model.policy, observations, targets, 40, seed, floor, 1e-3, 16, state)
    assert said_error() < 0.5 * before
    assert state.last_mse is not None and state.last_mse < 0.5 * before  # what fit says it left
    with_state = [p.detach().clone() for p in extractor.parameters()]
    for p, s0 in zip(extractor.parameters(), start, strict=True):
        p.data.copy_(s0)
    raw_fit(model.policy, observations, targets, 40, seed, floor, 1e-3, 16)
    assert not all(torch.equal(a, b) for a, b in zip(with_state, extractor.parameters()))


def test_a_round_store_gives_back_the_rows_and_the_policy_it_kept(tmp_path):
    """Pixel-like rows (a dict of uint8 images and float states) and the teacher's views, round
    by round: loaded back identical, dtypes kept, and the policy's parameters restored."""
    import torch

    from capture_bench.training.common.imitation_progress import Progress, RoundStore

    rng = np.random.default_rng(0)

    def batch():
        return {"image": rng.integers(0, 256, (2, 3, 8, 8), dtype=np.uint8),
                "state": rng.standard_normal((2, 7)).astype(np.float32)}  # fmt: skip

    policy = torch.nn.Linear(4, 2)
    store = RoundStore(tmp_path / "rounds")
    assert store.rounds_done() == 0 and store.load(policy)[0].rounds == 0
    done = Progress()
    for r in (1, 2):
        first = len(done.labels)
        for _ in range(3):
            done.observations.append(batch())
            done.labels.append(rng.standard_normal((2, 3)).astype(np.float32))
            done.views.append(rng.standard_normal((2, 16)).astype(np.float32))
        done.losses.append(0.1 * r)
        done.rounds = r
        store.save(done, first, policy)
    kept = [p.detach().clone() for p in policy.parameters()]
    fresh = torch.nn.Linear(4, 2)
    back, head = store.load(fresh)
    assert back.rounds == 2 == store.rounds_done() and back.losses == [0.1, 0.2] and head is None
    assert all(torch.equal(a, b) for a, b in zip(kept, fresh.parameters(), strict=True))
    for name in ("image", "state"):
        want = np.concatenate([b[name] for b in done.observations])
        got = np.concatenate([b[name] for b in back.observations])
        assert got.dtype == want.dtype and np.array_equal(got, want)
    assert np.array_equal(np.concatenate(back.labels), np.concatenate(done.labels))
    assert np.array_equal(np.concatenate(back.views), np.concatenate(done.views))
    store.clear()
    assert not (tmp_path / "rounds").exists()


def test_dagger_goes_on_from_its_last_stored_round(tmp_path):
    """One round stored, then a new model given the same store and two rounds: it starts from
    the stored policy and data set, plays only the second round, and its log holds both."""
    import torch

    from capture_bench.training.common.imitation_progress import RoundStore

    teacher = make_teacher(["incremental_ik"], [describe_task(load_scenario("paper"))], [4])
    store = RoundStore(tmp_path / "rounds")
    model, venv = _model(4)
    try:
        first = dagger(model, venv, teacher, rounds=1, steps=64, epochs=1, seed=0,
                       log=lambda line: None, store=store)  # fmt: skip
    finally:
        venv.close()
    after_one = {k: v.clone() for k, v in model.policy.state_dict().items()}
    lines: list[str] = []
    steps: list[int] = []
    model, venv = _model(4)
    real_step = venv.step

    def counted(actions):
        steps.append(len(actions))
        return real_step(actions)

    venv.step = counted
    loaded = {}

    def fit_spy(policy, observations, targets, *args, **kwargs):
        if not loaded:  # the second round's fit starts from the stored policy
            loaded.update({k: v.clone() for k, v in policy.state_dict().items()})
        return fit(policy, observations, targets, *args, **kwargs)

    from capture_bench.training.common import imitation

    real_fit, imitation.fit = imitation.fit, fit_spy
    try:
        second = dagger(model, venv, teacher, rounds=2, steps=64, epochs=1, seed=0,
                        log=lines.append, store=store)  # fmt: skip
    finally:
        imitation.fit = real_fit
        venv.close()
    assert all(torch.equal(after_one[k], loaded[k]) for k in after_one)
    assert len(steps) == 16  # one round of 64 steps on 4 envs, not two
    assert "1 of 2 rounds done before" in lines[0]
    assert second["fit_mse"][0] == first["fit_mse"][0] and len(second["fit_mse"]) == 2
    assert second["labelled_steps"] == 128 and store.rounds_done() == 2
    assert second["agreement"][0] is None and second["agreement"][1] is not None


def test_a_run_stopped_after_an_imitation_round_goes_on_from_it(tmp_path, monkeypatch, capsys):
    run_dir = tmp_path / "run"
    _stopped_in_round_two(run_dir, monkeypatch)
    assert "1 complete rounds kept" in capsys.readouterr().out
    assert (run_dir / "imitation_progress" / "round_1.npz").is_file()
    assert (run_dir / "wall_time.json").is_file()  # the stopped session's time is counted
    assert train.main(["--resume", str(run_dir)]) == 0
    assert "1 of 2 rounds done before" in capsys.readouterr().out
    done = json.loads((run_dir / "imitation.json").read_text())
    assert done["rounds"] == 2 and len(done["fit_mse"]) == 2 and done["labelled_steps"] == 128
    assert not (run_dir / "imitation_progress").exists()  # a checkpoint holds the policy


def test_a_run_lost_after_its_imitation_before_a_checkpoint_gets_its_policy_back(
    tmp_path, monkeypatch, capsys
):
    """Killed (here: an error) after imitation.json and before any checkpoint: the kept rounds
    give the imitated policy back; the folder goes once a checkpoint holds it."""
    from stable_baselines3 import PPO

    run_dir = tmp_path / "run"
    sets = [*TINY, "imitate=incremental_ik", "imitation_steps=64", "imitation_rounds=1",
            "imitation_epochs=1"]  # fmt: skip

    def lost(*args, **kwargs):
        raise RuntimeError("lost")

    monkeypatch.setattr(PPO, "learn", lost)
    with pytest.raises(RuntimeError, match="lost"):
        train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)])
    assert (run_dir / "imitation.json").is_file()
    assert not list((run_dir / "checkpoints").glob("step_*"))
    monkeypatch.undo()
    assert train.main(["--resume", str(run_dir)]) == 0
    assert "1 of 1 rounds done before" in capsys.readouterr().out
    assert not (run_dir / "imitation_progress").exists()


def test_kept_rounds_that_cannot_be_read_are_refused_in_one_line(tmp_path, monkeypatch, capsys):
    run_dir = tmp_path / "run"
    _stopped_in_round_two(run_dir, monkeypatch)
    (run_dir / "imitation_progress" / "round_1.npz").write_bytes(b"not an npz")
    capsys.readouterr()
    assert train.main(["--resume", str(run_dir)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "imitation_progress" in err[0] and "remove that folder" in err[0]


def _stopped_in_round_two(run_dir, monkeypatch) -> None:
    """A new two-round imitation run stopped (Ctrl-C) during its second round's fit."""
    from capture_bench.training.common import imitation

    sets = [*TINY, "imitate=incremental_ik", "imitation_steps=64", "imitation_rounds=2",
            "imitation_epochs=1"]  # fmt: skip
    real, calls = imitation.fit, []

    def stopped(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(imitation, "fit", stopped)
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) != 0
    monkeypatch.undo()
