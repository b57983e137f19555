"""The marker_pose front end (capture_bench/agents/marker_pose.py): from rendered pixel
observations it puts the capture point where the target is; its stack holds the last steps in
order and restarts with the episode; the training wrapper reads an ended episode's last
observation with that episode's pose; a run with it stores a policy that loads safely, evaluates
through evaluate.py and is refused in one line by an env it cannot read."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

import train
from capture_bench.agents.marker_pose import (
    DECIMETRES,
    POSE_WIDTH,
    STEP_WIDTH,
    MarkerCalibration,
    MarkerPoseAgent,
    MarkerPoseTracker,
    front_end_space,
    read_markers,
)
from capture_bench.agents.policy_file import PolicyLoadError
from capture_bench.agents.sb3_policy import (
    SB3Policy,
    load_policy,
    load_sb3_policy,
    load_trusted,
    read_metadata,
)
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.task.observation import decode_observation, pixel_observation_space
from capture_bench.training.common.front_end_vec_env import FrontEndVecEnv
from tests.stored_policies import assert_evaluates_in_pixel_envs

SIZE = (84, 84)
OPTIONS = {"observation_source": "pixels", "image_supersample": 3}


@pytest.fixture(scope="module")
def calibration():
    return MarkerCalibration.of_scenario("paper", SIZE)


def test_the_front_end_puts_the_capture_point_where_the_target_is(calibration):
    """Rendered frames of four episodes, the arm holding still: every step's pose is solved from
    the hand-read markers, and the capture point less X_E is the true one to 2 mm across the
    view and 10 mm in depth (y: the markers' spacing, docs/pixels.md); the features end with the
    arm's state."""
    env = CaptureVectorEnv(4, "paper", **OPTIONS)
    tracker = MarkerPoseTracker(calibration, 4, stack=2)
    errors = []
    try:
        obs, _ = env.reset(seed=[3, 4, 5, 6])
        for _ in range(4):
            features = tracker(obs)
            newest = features[:, STEP_WIDTH:]
            truth = decode_observation(env.true_observation(), env.description.control_period)
            assert np.all(newest[:, 3] == 1) and np.all(newest[:, 4] == 1)
            np.testing.assert_array_equal(newest[:, POSE_WIDTH:], obs["state"])
            errors.append(newest[:, :3] / DECIMETRES - (truth.target_position - truth.ee_position))
            obs = env.step(np.zeros((4, 3), dtype=np.float32))[0]
    finally:
        env.close()
    errors = np.abs(np.concatenate(errors))
    assert np.max(errors[:, [0, 2]]) < 2e-3 and np.max(errors[:, 1]) < 1e-2


def _observations(n: int, value: float) -> dict[str, np.ndarray]:
    """Pixel observations of ``n`` rows with a blank (white) image and the state all ``value``:
    no marker shows, so the pose features stay 0 and the state says which step it is."""
    return {
        "image": np.full((n, 3, *SIZE), 255, dtype=np.uint8),
        "state": np.full((n, 7), value, dtype=np.float32),
    }


def test_the_stack_holds_the_last_steps_in_order_and_restarts_with_the_episode(calibration):
    tracker = MarkerPoseTracker(calibration, 2, stack=3)
    first = tracker(_observations(2, 1.0)).reshape(2, 3, STEP_WIDTH)
    assert np.all(first[..., POSE_WIDTH:] == 1.0)  # the first step fills the stack
    assert np.all(first[..., :POSE_WIDTH] == 0.0)  # no marker: no pose, nothing solved
    tracker(_observations(2, 2.0))
    third = tracker(_observations(2, 3.0)).reshape(2, 3, STEP_WIDTH)
    np.testing.assert_array_equal(third[:, :, POSE_WIDTH], [[1, 2, 3], [1, 2, 3]])  # oldest first
    tracker.restart([1])
    after = tracker(_observations(2, 4.0)).reshape(2, 3, STEP_WIDTH)
    np.testing.assert_array_equal(after[:, :, POSE_WIDTH], [[2, 3, 4], [4, 4, 4]])
    only = tracker(_observations(1, 5.0), rows=[1]).reshape(1, 3, STEP_WIDTH)
    np.testing.assert_array_equal(only[0, :, POSE_WIDTH], [4, 4, 5])  # row 0 left as it was
    np.testing.assert_array_equal(tracker.history[0, :, POSE_WIDTH], [2, 3, 4])


def test_a_pose_is_kept_until_the_episode_restarts(calibration):
    """Hand-read markers 2-4, warm-started from the four markers' pose, give that pose to 3 mm
    (in depth; it is the branch that the warm start picks); a step with two keeps it; a
    restarted row has none."""
    env = CaptureVectorEnv(2, "paper", **OPTIONS)
    try:
        obs, _ = env.reset(seed=[3, 4])
        pixels, shown = read_markers(obs["image"])
        x_e = obs["state"][:, 3:6].astype(float)
    finally:
        env.close()
    assert shown.all()
    tracker = MarkerPoseTracker(calibration, 2)
    four = tracker.pose(pixels, shown, x_e)
    three = tracker.pose(pixels, shown & [False, True, True, True], x_e)
    np.testing.assert_allclose(three[:, :3], four[:, :3], atol=0.03)  # dm: 3 mm
    kept = tracker.pose(pixels + 3.0, shown & [False, False, True, True], x_e)
    assert np.all(kept[:, 3] == 0) and np.array_equal(kept[:, :3], three[:, :3])
    tracker.restart([0])
    again = tracker.pose(pixels, shown & [False, False, True, True], x_e)
    assert np.all(again[0, :3] == 0) and np.array_equal(again[1, :3], three[1, :3])


class _Steps(gym.Env):
    """A pixel env whose state counts its episode's steps (from 1) and that ends an episode
    after ``length`` steps."""

    observation_space = pixel_observation_space(SIZE)
    action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

    def __init__(self, length: int) -> None:
        self.length, self.t = length, 0

    def _obs(self) -> dict[str, np.ndarray]:
        return {k: v[0] for k, v in _observations(1, float(self.t + 1)).items()}

    def reset(self, *, seed=None, options=None):
        self.t = 0
        return self._obs(), {}

    def step(self, action):
        self.t += 1
        return self._obs(), 0.0, self.t >= self.length, False, {}


def test_the_training_wrapper_reads_the_ended_episode_then_restarts(calibration):
    venv = FrontEndVecEnv(DummyVecEnv([lambda: _Steps(3), lambda: _Steps(5)]), calibration, 2)
    assert venv.observation_space == front_end_space(2)
    obs = venv.reset()
    step = POSE_WIDTH  # the state's first entry in each step's features
    np.testing.assert_array_equal(obs[:, [step, STEP_WIDTH + step]], [[1, 1], [1, 1]])
    for _ in range(2):
        obs, _, dones, infos = venv.step(np.zeros((2, 3), dtype=np.float32))
    np.testing.assert_array_equal(obs[:, [step, STEP_WIDTH + step]], [[2, 3], [2, 3]])
    obs, _, dones, infos = venv.step(np.zeros((2, 3), dtype=np.float32))
    assert list(dones) == [True, False]
    last = infos[0]["terminal_observation"]
    np.testing.assert_array_equal(last[[step, STEP_WIDTH + step]], [3, 4])  # the ended episode's
    np.testing.assert_array_equal(obs[:, [step, STEP_WIDTH + step]], [[1, 1], [3, 4]])


def test_the_agent_acts_alike_on_one_observation_and_a_batch_and_forgets_at_reset(calibration):
    class Echo:  # the newest step's first state entry as every joint's action
        def predict(self, features, deterministic=True):
            x = np.asarray(features)
            return np.repeat(x[:, -STEP_WIDTH + POSE_WIDTH, None], 3, axis=1), None

    agent = MarkerPoseAgent(Echo(), calibration, stack=2)
    single = {k: v[0] for k, v in _observations(1, 0.25).items()}
    action, _ = agent.predict(single)
    assert action.shape == (3,) and np.all(action == 0.25)
    assert agent.tracker.n == 1 and not agent.tracker.fresh[0]
    agent.reset()
    assert agent.tracker.fresh[0]
    batch, _ = agent.predict(_observations(3, 0.5))
    assert batch.shape == (3, 3) and np.all(batch == 0.5)


TINY = ["n_envs=2", "n_steps=16", "batch_size=16", "n_epochs=1", "policy_kwargs.net_arch=[8]",
        "total_timesteps=32", "checkpoint_freq=0", "eval_freq=32", "eval_episodes=2",
        "imitation_rounds=1", "imitation_steps=16", "imitation_epochs=1", "imitation_batch=8",
        "imitation_warmup=32", "image_supersample=1"]  # fmt: skip
POSE = ["--observation-source", "pixels", "--config", "configs/pixels/ppo_pose.yaml"]


@pytest.fixture(scope="module")
def pose_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("pose") / "run"
    assert train.main([*POSE, *(f"--set={s}" for s in TINY), "--run-dir", str(run)]) == 0
    return run


def test_a_front_end_run_stores_a_policy_that_loads_safely_and_evaluates(pose_run, tmp_path):
    meta = json.loads((pose_run / "metadata.json").read_text())
    assert meta["front_end"] == {"name": "marker_pose", "stack": 3, "image_size": [84, 84]}
    metadata = read_metadata(pose_run)
    assert metadata.env_options == {"observation_source": "pixels", "image_size": (84, 84)}
    safe, trusted = load_policy(metadata), load_trusted(metadata)
    with CaptureEnv("paper", **metadata.env_options) as env:
        agents = [load.agent("m", env.description, env) for load in (safe, trusted)]
        assert isinstance(agents[0], MarkerPoseAgent)
        assert isinstance(agents[0].learned, SB3Policy)
        obs, _ = env.reset(seed=5)
        for _ in range(3):
            actions = [agent.predict(obs)[0] for agent in agents]
            np.testing.assert_array_equal(actions[0], actions[1])
            obs = env.step(actions[0])[0]
    assert_evaluates_in_pixel_envs(pose_run, tmp_path / "reports")


def test_shipping_a_front_end_run_says_it_sees_pixels_through_the_front_end(pose_run, tmp_path):
    from capture_bench.training.train.model_card import ship

    target = ship(pose_run, "pose", episodes=2, out=tmp_path / "models")
    card = json.loads((target / "metadata.json").read_text())
    assert card["front_end"]["name"] == "marker_pose"
    assert len(card["model_card"]["validation"]["paper"]["episodes"]) == 2
    readme = (target / "README.md").read_text()
    assert "from the camera's pixels" in readme and "`marker_pose` front end" in readme
    assert "--suite pixels" in readme and "reports/published/default" not in readme


@pytest.mark.parametrize(
    ("options", "words"),
    [
        ({}, ["front end marker_pose", "observation_source='pixels'"]),
        ({"observation_source": "pixels", "frame_stack": 2}, ["frame_stack 1"]),
        ({"observation_source": "pixels", "image_size": (64, 64)}, ["image_size=(84, 84)"]),
    ],
)
def test_a_front_end_model_on_an_env_it_cannot_read_is_one_line(pose_run, options, words):
    with CaptureEnv("paper", **options) as env:
        with pytest.raises(PolicyLoadError) as caught:
            load_sb3_policy(pose_run, env)
    message = str(caught.value)
    assert "\n" not in message and all(w in message for w in words), message


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--set", "front_end=marker_pose"], ["'front_end'", "pixels"]),
        (
            [
                *POSE,
                "--set",
                "policy=MultiInputPolicy",
                "--set",
                "policy_kwargs.features_extractor=combined",
            ],
            ["MlpPolicy"],
        ),
        ([*POSE, "--set", "frame_stack=3"], ["frame_stack 1"]),
        ([*POSE, "--set", "augment_shift=4"], ["augment_shift"]),
        ([*POSE, "--set", "policy_kwargs.features_extractor=relative_log_distance"], ["flatten"]),
        (["--set", "front_end_stack=2"], ["front_end_stack", "front_end"]),
        ([*POSE, "--set", "front_end=pose"], ["front_end", "marker_pose"]),
        ([*POSE, "--set", "imitation_state_weight=1"], ["imitation_state_weight", "flatten"]),
    ],
)
def test_a_front_end_it_cannot_have_is_one_line(tmp_path, capsys, argv, words):
    assert train.main([*argv, "--run-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(w in err for w in words), err


def test_the_memory_estimate_counts_the_front_ends_vector_not_images():
    from capture_bench.task.scenarios import load_scenario
    from capture_bench.training.config.settings import resolve_settings

    pose, _, _ = resolve_settings("ppo", load_scenario("paper"), "configs/pixels/ppo_pose.yaml")
    parts = dict((what, size) for _, what, size in pose.memory_estimate(True))
    rows = 4 * 16000  # imitation_rounds x imitation_steps, 32 envs dividing 16,000
    # three copies of each row: the vector (3 steps x STEP_WIDTH float32) and two actions
    assert parts["the imitation's data set"] == 3 * rows * (3 * STEP_WIDTH * 4 + 2 * 3 * 4)
    assert parts["the rollout buffer"] == 2 * 64 * 32 * (3 * STEP_WIDTH + 3 + 6) * 4


def test_a_bad_front_end_entry_in_the_metadata_is_one_line(pose_run, tmp_path):
    import shutil

    copy = tmp_path / "model"
    shutil.copytree(pose_run, copy, ignore=shutil.ignore_patterns("tb", "checkpoints", "best"))
    meta = json.loads((copy / "metadata.json").read_text())
    meta["front_end"] = {"name": "marker_pose", "stack": 0, "image_size": [84, 84]}
    (copy / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(PolicyLoadError) as caught:
        read_metadata(copy)
    assert "\n" not in str(caught.value) and "'front_end'" in str(caught.value)
