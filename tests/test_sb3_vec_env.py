"""``CaptureSB3VecEnv`` against SB3's ``DummyVecEnv`` of single envs, and SB3's use of it.

The reference is what ``train.py`` builds today: ``DummyVecEnv`` of
``TrainingSeeds(CaptureEnv(reuse_target_side=True))``, rank i's draw seeded ``seed * 1000 + i``.
Every observation, reward, done, terminal observation, ``TimeLimit.truncated``, ``info`` value
and reset ``info`` must agree across several same-step resets: floats to ~1e-9 (the batched
arithmetic may differ from the single env's in the last bits), everything discrete exactly.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.task.scenarios import load_scenario
from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv
from capture_bench.training.seeds import TrainingSeeds

N = 4
SEED = 3
DISCRETE = {
    "is_success",
    "failure",
    "saturated",
    "clipped",
    "target_visible",
    "estimator_status",
    "TimeLimit.truncated",
}


@pytest.fixture(scope="module")
def short_scenario():
    """Paper with 2 s episodes (40 control periods), so that episodes end often."""
    return load_scenario("paper").replace(control={"episode_limit": 2.0})


def _reference(scenario) -> DummyVecEnv:
    def make(rank: int):
        return lambda: TrainingSeeds(
            CaptureEnv(scenario, reuse_target_side=True), scenario, seed=SEED * 1000 + rank
        )

    return DummyVecEnv([make(i) for i in range(N)])


def _assert_same_info(ref: dict, got: dict, where: str) -> None:
    assert set(got) == set(ref), (where, set(got) ^ set(ref))
    for key, value in ref.items():
        if key == "terminal_observation":
            np.testing.assert_allclose(got[key], value, rtol=1e-6, atol=1e-7, err_msg=where)
            assert got[key].dtype == value.dtype, where
        elif key in DISCRETE or value is None or got[key] is None:
            assert got[key] == value and type(got[key]) is type(value), (where, key)
        else:
            assert isinstance(got[key], float), (where, key, type(got[key]))
            assert math.isclose(got[key], value, rel_tol=1e-9, abs_tol=1e-9) or (
                math.isnan(value) and math.isnan(got[key])
            ), (where, key, got[key], value)


@pytest.mark.parametrize("sb3_seed", [None, 11])
def test_transitions_match_dummy_vec_env_across_resets(short_scenario, sb3_seed):
    """Incremental IK on half the sub-envs (captures), random actions on the rest (failures
    and time limits); ``sb3_seed``: the seed SB3's model passes to ``VecEnv.seed``."""
    ref = _reference(short_scenario)
    got = CaptureSB3VecEnv(N, short_scenario, seed=SEED)
    if sb3_seed is not None:
        assert got.seed(sb3_seed) == ref.seed(sb3_seed)
    obs, obs_b = ref.reset(), got.reset()
    np.testing.assert_allclose(obs_b, obs, rtol=1e-6, atol=1e-7)
    assert obs_b.dtype == obs.dtype and obs_b.shape == obs.shape
    assert got.get_attr("episode_seed") == ref.get_attr("episode_seed")
    for i in range(N):
        _assert_same_info(ref.reset_infos[i], got.reset_infos[i], f"reset {i}")
    agents = [make_agent("incremental_ik", ref.envs[i]) for i in range(N // 2)]
    rng = np.random.default_rng(0)
    outcomes: set = set()
    ends = np.zeros(N, dtype=int)
    for t in range(130):
        actions = rng.uniform(-1, 1, (N, 3)).astype(np.float32)
        for i, agent in enumerate(agents):
            actions[i] = agent.predict(obs[i])[0]
        obs, rewards, dones, infos = ref.step(actions)
        obs_b, rewards_b, dones_b, infos_b = got.step(actions)
        where = f"step {t}"
        np.testing.assert_array_equal(dones_b, dones, err_msg=where)
        np.testing.assert_allclose(obs_b, obs, rtol=1e-6, atol=1e-7, err_msg=where)
        np.testing.assert_allclose(rewards_b, rewards, rtol=1e-6, atol=1e-9, err_msg=where)
        assert rewards_b.dtype == rewards.dtype and dones_b.dtype == dones.dtype, where
        assert isinstance(infos_b, list) and len(infos_b) == N
        for i in range(N):
            _assert_same_info(infos[i], infos_b[i], f"{where}, env {i}")
        for i in np.flatnonzero(dones).tolist():
            _assert_same_info(ref.reset_infos[i], got.reset_infos[i], f"{where}, reset {i}")
            outcomes.add("capture" if infos[i]["is_success"] else str(infos[i]["failure"]))
            if i < len(agents):
                agents[i].reset()
        ends += dones
        assert got.get_attr("episode_seed") == ref.get_attr("episode_seed"), where
    assert ends.min() >= 3, ends  # every sub-env went through several resets
    assert {"capture", "timeout"} <= outcomes, outcomes  # terminated, and truncated
    ref.close()
    got.close()


def test_episode_seeds_are_training_seeds(short_scenario):
    env = CaptureSB3VecEnv(2, short_scenario, seed=0)
    env.seed(5)
    env.reset()
    seeds = set(env.get_attr("episode_seed"))
    for _ in range(90):
        env.step(np.ones((2, 3), dtype=np.float32))
        seeds |= set(env.get_attr("episode_seed"))
    assert len(seeds) >= 4
    assert all(s in short_scenario.training_seeds for s in seeds)
    forbidden = set(short_scenario.evaluation_seeds) | set(short_scenario.validation_seeds)
    assert not seeds & forbidden
    env.close()
    env.close()  # safe twice


def test_what_sb3_asks_of_it(short_scenario):
    env = CaptureSB3VecEnv(2, short_scenario, seed=0, reward="sparse")
    assert env.render_mode is None and env.get_attr("render_mode") == [None, None]
    assert env.get_attr("reward_mode", indices=[1]) == ["sparse"]
    assert env.env_is_wrapped(TrainingSeeds) == [False, False]
    env.set_attr("some_flag", 3)
    assert env.get_attr("some_flag") == [3, 3]
    with pytest.raises(ValueError, match="indices=None"):
        env.set_attr("some_flag", 4, indices=[0])
    with pytest.raises(RuntimeError, match="step_async"):
        env.step_wait()
    env.set_options({"x": 1})
    with pytest.raises(ValueError, match="no options"):
        env.reset()
    env.close()


def test_a_tiny_ppo_learns_on_it(short_scenario):
    env = VecMonitor(CaptureSB3VecEnv(2, short_scenario, seed=0))
    model = PPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu",
                policy_kwargs={"net_arch": [16]})  # fmt: skip
    model.learn(64)
    assert model.num_timesteps == 64
    env.close()


def _assert_same_run(ref: DummyVecEnv, got: CaptureSB3VecEnv, steps: int, where: str) -> int:
    """Reset both, step both with the same random actions; how many episodes ended."""
    np.testing.assert_allclose(got.reset(), ref.reset(), rtol=1e-6, atol=1e-7, err_msg=where)
    rng = np.random.default_rng(1)
    ended = 0
    for t in range(steps):
        actions = rng.uniform(-1, 1, (N, 3)).astype(np.float32)
        obs, rewards, dones, _ = ref.step(actions)
        obs_b, rewards_b, dones_b, _ = got.step(actions)
        np.testing.assert_array_equal(dones_b, dones, err_msg=f"{where}, step {t}")
        np.testing.assert_allclose(obs_b, obs, rtol=1e-6, atol=1e-7, err_msg=f"{where}, step {t}")
        np.testing.assert_allclose(rewards_b, rewards, rtol=1e-6, atol=1e-9)
        assert got.get_attr("episode_seed") == ref.get_attr("episode_seed"), (where, t)
        ended += int(dones.sum())
    return ended


def test_a_reseed_discards_the_episodes_recorded_ahead(short_scenario):
    """After SB3's ``seed()`` + ``reset()`` mid-run, the episodes are those of a fresh
    ``DummyVecEnv`` seeded the same, not the ones recorded ahead from the old draws."""
    got = CaptureSB3VecEnv(N, short_scenario, seed=SEED)
    assert _assert_same_run(_reference(short_scenario), got, 50, "first run") >= N
    ref = _reference(short_scenario)
    assert got.seed(21) == ref.seed(21)
    assert _assert_same_run(ref, got, 50, "after seed(21)") >= N
    ref.close()
    got.close()


def test_episodes_are_recorded_in_batches(short_scenario, monkeypatch):
    """Every training episode is explicitly seeded, yet recorded many at a time (a spy on
    ``record_episodes``; not a timing)."""
    from capture_bench.engine import sides

    sizes: list[int] = []
    original = sides.record_episodes

    def spy(*args, **kwargs):
        sizes.append(len(args[-1]))
        return original(*args, **kwargs)

    monkeypatch.setattr(sides, "record_episodes", spy)
    env = CaptureSB3VecEnv(N, short_scenario, seed=SEED)
    env.reset()
    started = N
    for _ in range(130):
        started += int(env.step(np.ones((N, 3), dtype=np.float32))[2].sum())
    assert started >= 3 * N
    assert sum(sizes) >= started and min(sizes) >= N, sizes
    assert len(sizes) <= started / (2 * N), sizes
    env.close()
