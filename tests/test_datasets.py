"""``python -m capture_bench dataset``: a recorded Minari dataset replays bit for bit in the env
it recovers, holds the env's spaces and each episode's seed, refuses published seeds and bad input
in one line, and an interrupted recording resumes without a duplicate episode."""

import json

import gymnasium as gym
import numpy as np
import pytest

minari = pytest.importorskip("minari")
pytest.importorskip("h5py")

from capture_bench.datasets import command, recording  # noqa: E402

DATASET = "capture-bench/paper/test-v0"
SEEDS = [0, 1, 2]


def _record(root, *extra):
    return command.main(["--scenario", "paper", "--root", str(root), *extra])


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two agents (the oracle and planned_intercept) on training seeds 0-2 of paper, with the true
    target state, in a Minari root of its own; the dataset loaded with ``minari.load_dataset``."""
    root = tmp_path_factory.mktemp("minari")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MINARI_DATASETS_PATH", str(root))
        status = _record(
            root, "--agents", "oracle,planned_intercept", "--episodes", "3", "--privileged",
            "--id", DATASET,
        )  # fmt: skip
        assert status == 0
        dataset = minari.load_dataset(DATASET)  # from the local path the variable names
        yield root, dataset


def _metadata(dataset):
    return list(dataset.storage.get_episode_metadata(range(dataset.total_episodes)))


def test_a_recorded_dataset_replays_bit_for_bit(recorded):
    _, dataset = recorded
    env = dataset.recover_environment()
    try:
        for episode, meta in zip(dataset.iterate_episodes(), _metadata(dataset)):
            obs, _ = env.reset(seed=meta["seed"])
            np.testing.assert_array_equal(obs, episode.observations[0])
            for k, action in enumerate(episode.actions):
                obs, reward, terminated, truncated, info = env.step(action)
                np.testing.assert_array_equal(obs, episode.observations[k + 1])
                assert reward == episode.rewards[k]
                assert (terminated, truncated) == (
                    episode.terminations[k], episode.truncations[k],
                )  # fmt: skip
                _assert_info_row(info, episode.infos, k + 1)
            assert terminated or truncated
            truth = env.unwrapped.recorded_episode
            n = len(episode) + 1
            np.testing.assert_array_equal(episode.infos["true_target_position"], truth.position[:n])
            np.testing.assert_array_equal(episode.infos["true_target_velocity"], truth.velocity[:n])
            _assert_covariance_gives_the_nees(episode.infos, truth, n)
    finally:
        env.close()


def _assert_covariance_gives_the_nees(infos, truth, n):
    """The recorded covariance P is the estimator's: symmetric, positive definite where the
    filter has one, NaN where it has none, and with the estimate's error against the true state it
    gives the env's NEES, e^T P^-1 e, row by row (reset's, which its ``info`` does not carry, the
    recording's)."""
    covariance = infos["estimate_covariance"]
    assert covariance.shape == (n, 6, 6)
    has = np.isfinite(covariance).all(axis=(1, 2))
    assert has.sum() > n // 2
    assert np.isnan(covariance[~has]).all()
    p = covariance[has]
    np.testing.assert_allclose(p, np.swapaxes(p, 1, 2), rtol=0, atol=1e-12)
    assert (np.linalg.eigvalsh(p)[:, 0] > 0).all()
    error = np.concatenate([
        truth.estimate_position[:n] - infos["true_target_position"],
        truth.estimate_velocity[:n] - infos["true_target_velocity"],
    ], axis=1)[has]  # fmt: skip
    nees = np.einsum("ki,ki->k", error, np.linalg.solve(p, error[:, :, None])[:, :, 0])
    env_nees = np.where(np.arange(n) == 0, truth.nees[:n], infos["estimate_nees"])  # reset: NaN
    np.testing.assert_allclose(nees, env_nees[has], rtol=1e-9)


def _assert_info_row(info, rows, k):
    """Step ``k``'s ``info`` equals row ``k`` of the dataset's: numbers (None as NaN), flags, text
    (None as "")."""
    for key, value in info.items():
        if key == "physical_limit_time":  # the episode's metadata, not a row
            continue
        stored = rows[key][k]
        if isinstance(stored, bytes):
            assert stored.decode() == ("" if value is None else value), key
        elif value is None:
            assert np.isnan(stored), key
        else:
            assert stored == value, key


def test_the_spaces_are_the_envs_and_every_episode_has_its_seed_and_agent(recorded):
    _, dataset = recorded
    env = gym.make("CaptureBench/Paper-v1")
    try:
        assert dataset.observation_space == env.observation_space
        assert dataset.action_space == env.action_space
    finally:
        env.close()
    assert dataset.env_spec.id == "CaptureBench/Paper-v1"
    meta = _metadata(dataset)
    assert [(m["seed"], m["agent"]) for m in meta] == [
        (s, a) for s in SEEDS for a in ("oracle", "planned_intercept")
    ]
    assert all(m["outcome"] in ("captured", "failed") for m in meta)
    info = dataset[0].infos
    assert len(info["estimate_nees"]) == len(dataset[0]) + 1  # reset's row first
    assert info["failure"][0] == b""


def test_the_metadata_names_the_code_version(recorded):
    _, dataset = recorded
    ours = dataset.storage.metadata["capture_bench"]
    assert ours["version"] == __import__("capture_bench").__version__
    assert "commit" in ours["git"]
    assert ours["seed_set"] == "training" and ours["first_seed"] == 0 and ours["episodes"] == 3
    assert ours["privileged_agents"] == ["oracle"]


def _one_line(capsys):
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err
    return err


@pytest.mark.parametrize(
    "extra",
    [
        ["--first-seed", "1000000"],
        ["--first-seed", "999999", "--episodes", "3"],
        ["--seed-set", "evaluation"],
    ],
)
def test_a_published_seed_is_refused_in_one_line(tmp_path, capsys, monkeypatch, extra):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert _record(tmp_path, "--agents", "incremental_ik", *extra) == 2
    err = _one_line(capsys)
    assert "published evaluation seed" in err and "1000000-1000099" in err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--agents", "no_such_agent"], "unknown agent 'no_such_agent'"),
        (["--agents", "incremental_ik", "--scenario", "nowhere"], "nowhere"),
        (["--agents", "incremental_ik", "--id", "bad id"], "not a Minari dataset id"),
        (["--agents", "incremental_ik", "--id", "capture-bench/x"], "-v<N>"),
        (["--agents", "incremental_ik", "--episodes", "0"], "--episodes 0"),
        (["--agents", "incremental_ik", "--seed-set", "validation", "--first-seed", "5"],
         "validation seeds"),
    ],
)  # fmt: skip
def test_bad_input_is_one_line(tmp_path, capsys, monkeypatch, extra, says):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert _record(tmp_path, *extra) == 2
    assert says in _one_line(capsys)


def test_an_existing_dataset_is_not_overwritten(recorded, capsys, monkeypatch):
    root, _ = recorded
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    assert _record(root, "--agents", "incremental_ik", "--id", DATASET) == 2
    assert "already exists" in _one_line(capsys)


def test_an_interrupted_recording_resumes_without_duplicates(
    recorded, tmp_path, capsys, monkeypatch
):
    """Interrupted after two episodes, a recording keeps them; a second run without --resume
    is refused, one with it plays the missing ones only; the dataset equals an uninterrupted
    recording of the same seeds."""
    _, whole = recorded
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    played = []
    play = recording.play_episode

    def interrupted_after_two(*args, **kwargs):
        if len(played) == 2:
            raise KeyboardInterrupt
        played.append(kwargs["seed"])
        return play(*args, **kwargs)

    monkeypatch.setattr(recording, "play_episode", interrupted_after_two)
    args = [
        "--agents",
        "planned_intercept",
        "--episodes",
        "3",
        "--privileged",
        "--id",
        "test/resume-v0",
    ]
    assert _record(tmp_path, *args) == 130
    err = capsys.readouterr().err
    assert "2 of 3 episodes kept" in err and "--resume" in err
    staging = recording.staging_dir(tmp_path, "test/resume-v0")
    assert recording.staged(staging) == {(0, 0), (1, 0)}

    assert _record(tmp_path, *args) == 2
    assert "add --resume" in _one_line(capsys)
    assert (
        _record(tmp_path, *args[:-2], "--id", "test/resume-v0", "--first-seed", "1", "--resume")
        == 2
    )
    assert "first_seed" in _one_line(capsys)

    monkeypatch.setattr(
        recording, "play_episode", lambda *a, **k: played.append(k["seed"]) or play(*a, **k)
    )
    assert _record(tmp_path, *args, "--resume") == 0
    assert played == [0, 1, 2]  # seed 2 alone played again
    assert not staging.exists()
    dataset = minari.load_dataset("test/resume-v0")
    assert [m["seed"] for m in _metadata(dataset)] == SEEDS
    expected = [
        e
        for e, m in zip(whole.iterate_episodes(), _metadata(whole))
        if m["agent"] == "planned_intercept"
    ]
    for got, want in zip(dataset.iterate_episodes(), expected, strict=True):
        np.testing.assert_array_equal(got.observations, want.observations)
        np.testing.assert_array_equal(got.actions, want.actions)
        np.testing.assert_array_equal(got.rewards, want.rewards)
    meta = json.loads((tmp_path / "test/resume-v0/data/metadata.json").read_text())
    assert meta["total_episodes"] == 3


def test_behaviour_cloning_from_a_dataset_writes_a_model_evaluate_loads(recorded, tmp_path):
    """scripts/bc_from_dataset.py: a policy of a shipped model's shape, fitted to the dataset's
    pairs, written as a model directory that agent specs resolve and play."""
    import importlib.util
    from pathlib import Path

    from capture_bench.datasets.episodes import play_episode
    from capture_bench.evaluation.running.agents_loading import (
        build_agent,
        check_agent,
        resolve_agent,
    )

    root, _ = recorded
    path = Path(__file__).resolve().parents[1] / "scripts" / "bc_from_dataset.py"
    spec = importlib.util.spec_from_file_location("bc_from_dataset", path)
    bc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bc)
    out = tmp_path / "bc"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MINARI_DATASETS_PATH", str(root))
        argv = ["--dataset", DATASET, "--root", str(root), "--out", str(out), "--epochs", "2",
                "--agent", "planned_intercept"]  # fmt: skip
        assert bc.main(argv) == 0
    card = json.loads((out / "metadata.json").read_text())["model_card"]
    assert card["dataset"] == DATASET and card["episodes"] == 3
    assert card["agents"] == ["planned_intercept"] and card["dataset_seeds"] == SEEDS
    agent = resolve_agent(str(out))
    env = gym.make("CaptureBench/Paper-v1")
    try:
        check_agent(agent, env, "paper")
        episode = play_episode(
            env, build_agent(agent, env, 0), label=agent.label, seed=0, privileged=False
        )
    finally:
        env.close()
    assert episode.steps > 0


def test_python_m_capture_bench_dataset_runs_the_command(tmp_path, capsys, monkeypatch):
    from capture_bench.__main__ import main

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert main(["dataset", "--agents", "nope", "--scenario", "paper"]) == 2
    assert _one_line(capsys).startswith("python -m capture_bench dataset: error: unknown agent")
    assert main(["dataset", "--help"]) == 0
    assert "--privileged" in capsys.readouterr().out
