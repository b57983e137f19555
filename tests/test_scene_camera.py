"""The rendered camera in an episode: the fast path (target-only frames rendered once per seed and
reused where the arm cannot reach, windows) against rendering every frame in full with the arm,
episode by episode."""

from __future__ import annotations

import numpy as np
import pytest

from capture_bench.agents import make_agent
from capture_bench.engine.cache import EpisodeCache
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.sensing.scene_camera import RenderedSceneCamera
from capture_bench.task.scenarios import load_scenario


def _play(env: CaptureEnv, agent_name: str, seed: int) -> list[tuple]:
    """Every step of one episode: observation, reward, flags and the target-side info."""
    obs, _ = env.reset(seed=seed)
    agent = make_agent(agent_name, env)
    steps = [(obs.tolist(),)]
    done = False
    while not done:
        action, _ = agent.predict(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        done = terminated or truncated
        steps.append(
            (
                obs.tolist(),
                reward,
                terminated,
                truncated,
                info["failure"],
                info["estimator_status"],
                info["target_visible"],
                info["capture_time"],
                env.engine.sides.sides[0].camera_episode.last_detections.found.tolist(),
            )
        )
    return steps


@pytest.fixture(scope="module")
def reference_env():
    """Every frame rendered in full (1280 x 960) with the arm, no store: the reference."""
    env = CaptureEnv("grasp_rendered")
    env.engine.sides.camera.close()
    env.engine.sides.camera = RenderedSceneCamera.for_scenario(env.task.scenario, windowed=False)
    yield env
    env.close()


def test_reused_target_frames_and_windows_play_the_episodes_of_full_frames(reference_env):
    """Two agents on the same seeds: the first renders each frame of the target alone once, the
    second reuses them; each frame the arm may reach is rendered with it. Both play exactly the
    episodes the full-frame reference plays, the arm hiding markers on the way."""
    cache = EpisodeCache()
    fast = CaptureEnv("grasp_rendered", reuse_target_side=True, episode_cache=cache)
    seeds = load_scenario("grasp_rendered").evaluation_seeds[:2]
    hidden = 0
    try:
        for agent in ("incremental_ik", "pure_pursuit"):
            for seed in seeds:
                expected = _play(reference_env, agent, seed)
                assert _play(fast, agent, seed) == expected, (agent, seed)
                hidden += sum(1 for step in expected[1:] if not all(step[-1]))
        renders = fast.engine.sides.camera.renders
        assert renders["reused"] > 0 and renders["with_arm"] > 0 and renders["target_only"] > 0
    finally:
        fast.close()
    assert hidden > 0  # some frames had a marker hidden (by the arm, as it holds the target)


def test_a_frame_the_arm_covers_is_rendered_with_it():
    """The arm's bounding boxes decide: a marker behind the end-effector is reported hidden by
    the geometric test and missing in the image, one far from the arm is not."""
    sc = load_scenario("paper_rendered")
    camera = RenderedSceneCamera.for_scenario(sc)
    try:
        home = np.array(sc_home())
        boxes = camera.link_boxes(home)
        tip = boxes[-1].mean(axis=0)  # the end-effector link's box centre
        lens = camera.model.position
        behind = tip + 0.3 * (tip - lens) / np.linalg.norm(tip - lens)  # markers behind the tip
        rotation = np.eye(3)

        def pose_at(_t, where=behind):
            return where, rotation

        assert camera.arm_may_hide(pose_at, 0.0, lambda _t: home)
        found = camera.detect(pose_at, 0.0, lambda _t: home, 0)
        assert not found.found[0]
        far = behind + np.array([0.0, 0.0, 0.45])
        assert not camera.arm_may_hide(lambda _t: (far, rotation), 0.0, lambda _t: home)
    finally:
        camera.close()


def sc_home():
    from capture_bench.sim.kinematics import HOME

    return HOME


def test_episodes_interleaved_on_one_camera_see_what_each_sees_alone():
    """An episode's state (noise key, latency pipeline, count, flags, detections, target-only
    store) is its `SceneEpisode`: two episodes whose frames are taken in turn on one camera get,
    frame by frame, what each gets alone on it, image noise, drop-out and latency included."""
    from capture_bench.sensing.rendered_sensor import RenderSettings
    from capture_bench.sensing.scene_camera import joint_path
    from capture_bench.sim.target_motion import FEATURE_POINTS
    from capture_bench.task.episode import EpisodePlan

    sc = load_scenario("paper_rendered")
    features = FEATURE_POINTS[sc.target.feature_points]
    settings = RenderSettings(marker_radius=sc.camera.marker_radius, image_noise=4.0)
    camera = RenderedSceneCamera(sc.camera.model(), features, settings, 0.2, 1)
    home = np.array(sc_home())
    plans = [
        EpisodePlan.draw(sc, camera.model, features, np.random.default_rng(seed)) for seed in (3, 4)
    ]
    frames = 12

    def arm_at(j, k):  # the arm swings toward the target and back, differently per episode
        reach = home + (0.3 + 0.2 * j) * np.sin(0.5 * k) * np.array([1.0, -0.6, 0.8])
        return joint_path(home, reach, 0.0, 1.0)

    def seen(state, frame):
        got = None
        if frame is not None:
            got = (frame.image_points.tobytes(), frame.capture_index, frame.found.tolist())
        found = state.last_detections
        detected = None if found is None else (found.pixels.tobytes(), found.status.tolist())
        return got, state.last_visible, state.last_dropped, detected

    def start(j):
        rng = np.random.default_rng(10 + j)
        return camera.reset(rng, target_only={}), rng

    def take(j, k, state, rng):
        time = float(plans[j].step_times()[0][k])
        trajectory = plans[j].trajectory
        frame = camera.capture_scene(state, k, time, trajectory, arm_at(j, k), rng)
        return seen(state, frame)

    try:
        alone = []
        for j in (0, 1):
            state, rng = start(j)
            alone.append([take(j, k, state, rng) for k in range(frames)])
        started = [start(0), start(1)]
        together = [[], []]
        for k in range(frames):
            for j in (1, 0):
                together[j].append(take(j, k, *started[j]))
        assert together == alone
        assert started[0][0].target_only and started[0][0].noise_key != started[1][0].noise_key
        assert any(s[2] for s in alone[0] + alone[1])  # some frames dropped
        assert sum(s[0] is not None for s in alone[0]) > frames // 2
    finally:
        camera.close()


def test_the_batched_env_plays_the_single_envs_rendered_episodes():
    """CaptureVectorEnv with the rendered camera (one shared renderer, a camera view and an
    estimator per sub-env): the same records as the single env on the same seeds, the episodes
    ending at different steps."""
    from gymnasium.vector import AutoresetMode

    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.evaluation.running.rollout import TIMING_COLUMNS, run_episode, run_episodes

    seeds = load_scenario("paper_rendered").evaluation_seeds[:3]

    def fields(record):  # repr: NaN equals NaN there
        return {k: repr(v) for k, v in record.as_row().items() if k not in TIMING_COLUMNS}

    vector = CaptureVectorEnv(3, "paper_rendered", autoreset_mode=AutoresetMode.DISABLED)
    single = CaptureEnv("paper_rendered")
    try:
        agent = make_agent("incremental_ik", vector)
        batched = run_episodes(
            vector, agent, agent_name="ik", scenario="paper_rendered", seeds=seeds
        )
        for seed, record in zip(seeds, batched, strict=True):
            alone, _ = run_episode(
                single,
                make_agent("incremental_ik", single),
                agent_name="ik",
                scenario="paper_rendered",
                seed=seed,
            )
            assert fields(record) == fields(alone), seed
        assert len({r.steps for r in batched}) > 1
    finally:
        vector.close()
        single.close()


def test_rgb_array_shows_the_cameras_view_with_what_was_found():
    """render() of a rendered scenario: the camera's own image at render_size, a green ring on
    each marker found and the estimated capture point (yellow); the scene view on request; an
    analytic scenario has no camera view (one line naming the valid views)."""
    env = CaptureEnv("paper_rendered", render_mode="rgb_array", render_size=(320, 240))
    try:
        obs, _ = env.reset(seed=load_scenario("paper_rendered").evaluation_seeds[1])
        agent = make_agent("incremental_ik", env)
        for _ in range(5):
            obs, *_ = env.step(agent.predict(obs)[0])
        image = env.render()
        assert image.shape == (240, 320, 3) and image.dtype == np.uint8
        ring = (image[..., 0] == 0) & (image[..., 1] == 200) & (image[..., 2] == 0)
        assert ring.sum() > 20  # four rings of radius 6 px
        yellow = (image[..., 0] == 230) & (image[..., 1] == 180) & (image[..., 2] == 0)
        assert yellow.any()
    finally:
        env.close()
    scene = CaptureEnv("paper_rendered", render_mode="rgb_array", render_view="scene")
    assert scene.render_view == "scene"
    scene.close()
    with pytest.raises(ValueError, match="render_view must be one of"):
        CaptureEnv("paper", render_view="camera")


def test_train_py_trains_on_a_rendered_scenario(tmp_path):
    """train.py with the rendered camera: the batched env, two sub-envs sharing one renderer,
    a 64-step PPO run whose model is written."""
    import train

    config = tmp_path / "tiny.yaml"
    config.write_text(
        "n_envs: 2\ntotal_timesteps: 64\npolicy_kwargs: {net_arch: [16]}\nn_steps: 32\n"
        "batch_size: 32\nn_epochs: 1\ncheckpoint_freq: 64\n"
    )
    run_dir = tmp_path / "run"
    argv = ["--algo", "ppo", "--scenario", "paper_rendered", "--config", str(config)]
    assert train.main([*argv, "--run-dir", str(run_dir)]) == 0
    assert (run_dir / "policy.pt").is_file()


def test_env_checkers_pass_on_a_rendered_scenario():
    from gymnasium.utils.env_checker import check_env as gymnasium_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = CaptureEnv("paper_rendered")
    try:
        gymnasium_check(env, skip_render_check=True)
        sb3_check(env, warn=True)
    finally:
        env.close()


def test_the_same_seed_plays_the_same_rendered_rollout_twice_and_on_any_worker_count():
    """Rendered episodes through the evaluation's backends: in this process, again, and on two
    worker processes, the same records (timing aside)."""
    from capture_bench.evaluation.running.backends import EpisodeTask, close_envs, run_tasks
    from capture_bench.evaluation.running.rollout import TIMING_COLUMNS

    seeds = load_scenario("paper_rendered").evaluation_seeds[1:3]
    tasks = [
        EpisodeTask(agent, "paper_rendered", seed)
        for agent in ("incremental_ik", "pure_pursuit")
        for seed in seeds
    ]

    def rows(records):  # repr: NaN equals NaN there
        return [
            {k: repr(v) for k, v in r.as_row().items() if k not in TIMING_COLUMNS} for r in records
        ]

    try:
        first = rows(run_tasks(tasks, "serial"))
        assert rows(run_tasks(tasks, "serial")) == first
        assert rows(run_tasks(tasks, "process", workers=2)) == first
    finally:
        close_envs()


@pytest.mark.parametrize(
    ("camera", "key"),
    [
        ("mode: photo", "camera.mode"),
        ("resolution: [0, 960]", "camera.resolution"),
        ("marker_radius: -1", "camera.marker_radius"),
    ],
)
def test_a_bad_camera_value_is_one_line_naming_the_key(camera, key, tmp_path, capsys):
    from evaluate import main

    path = tmp_path / "bad.yaml"
    path.write_text(f"description: bad\ncamera:\n  {camera}\n")
    assert main(["--scenarios", str(path), "--agents", "hold", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and key in err[0] and "Traceback" not in err[0], err


def test_the_gif_of_a_rendered_scenario_shows_the_cameras_view():
    """The report's episodes to watch on a rendered scenario: the camera's own view, the
    markers found ringed green."""
    import io

    from PIL import Image

    from capture_bench.evaluation.running.backends import EpisodeTask
    from capture_bench.evaluation.running.video import record_video

    seed = load_scenario("paper_rendered").evaluation_seeds[1]
    video = record_video(EpisodeTask("incremental_ik", "paper_rendered", seed), steps=None)
    with Image.open(io.BytesIO(video.gif)) as gif:
        gif.seek(3)
        frame = np.asarray(gif.convert("RGB"))
    ring = (frame[..., 0] < 40) & (frame[..., 1] > 170) & (frame[..., 2] < 40)
    assert ring.sum() > 20
