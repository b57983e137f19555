"""``CaptureVectorEnv`` against N single envs, and its own contract.

The reference is gymnasium's ``SyncVectorEnv`` of ``CaptureEnv(reuse_target_side=True)`` (the
same seeding and next-step autoreset): every observation, reward, termination and ``info`` entry
must agree, floats to rounding (the batched arithmetic may differ in the last bits), everything
discrete exactly.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from references.joint_limits import apply_joint_increment

import capture_bench  # noqa: F401  (registers the envs)
from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.sim.collision_screen import clear_of_collisions
from capture_bench.sim.kinematics import reachable
from capture_bench.sim.target_motion import FEATURE_POINTS
from capture_bench.sim.world import World, limit_joint_increments

DISCRETE = ("is_success", "failure", "saturated", "clipped", "target_visible", "estimator_status")


def _pair(env_id: str, n: int, **kwargs):
    sync = gym.make_vec(env_id, n, vectorization_mode="sync", reuse_target_side=True, **kwargs)
    batched = gym.make_vec(env_id, n, vectorization_mode="vector_entry_point", **kwargs)
    assert isinstance(batched, CaptureVectorEnv)
    return sync, batched


def _as_float(values: np.ndarray) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=float)


def _assert_same_info(ref: dict, got: dict, where: str) -> None:
    for key, value in ref.items():
        if key.startswith("_"):
            continue
        mask = ref[f"_{key}"]
        np.testing.assert_array_equal(got[f"_{key}"], mask, err_msg=f"{where}: mask of {key}")
        if key in DISCRETE:
            assert list(got[key][mask]) == list(value[mask]), (where, key)
        else:
            np.testing.assert_allclose(
                got[key][mask].astype(float),
                _as_float(value[mask]),
                rtol=1e-6,  # photogrammetry's finite-difference velocity amplifies rounding
                atol=1e-8,
                err_msg=f"{where}: {key}",
            )
    extra = {k for k in got if not k.startswith("_") and got[f"_{k}"].any()} - set(ref)
    assert not extra, (where, extra)


def _run_pair(sync, batched, seed: int, steps: int, act) -> int:
    """Step both with the same actions; returns how many episodes ended."""
    obs, info = sync.reset(seed=seed)
    obs_b, info_b = batched.reset(seed=seed)
    np.testing.assert_allclose(obs_b, obs, atol=1e-6)
    _assert_same_info(info, info_b, "reset")
    ended = 0
    for t in range(steps):
        actions = act(obs, t)
        obs, reward, term, trunc, info = sync.step(actions)
        obs_b, reward_b, term_b, trunc_b, info_b = batched.step(actions)
        where = f"step {t}"
        np.testing.assert_array_equal(term_b, term, err_msg=where)
        np.testing.assert_array_equal(trunc_b, trunc, err_msg=where)
        np.testing.assert_allclose(reward_b, reward, rtol=1e-7, atol=1e-9, err_msg=where)
        np.testing.assert_allclose(obs_b, obs, atol=1e-5, err_msg=where)
        _assert_same_info(info, info_b, where)
        ended += int(term.sum() + trunc.sum())
    return ended


@pytest.mark.parametrize(
    ("env_id", "source"),
    [
        ("CaptureBench/Paper-v1", None),
        ("CaptureBench/Noisy-v1", None),  # drop-outs, divergences, target_lost
        ("CaptureBench/Jitter-v1", None),  # episodes of different lengths in one batch
        ("CaptureBench/Evasive-v1", None),
        ("CaptureBench/Tumbling-v1", "photogrammetry"),
        ("CaptureBench/Circular-v1", "truth"),
        ("CaptureBench/Grasp-v1", None),  # a hold
    ],
)
def test_random_actions_match_single_envs_across_autoresets(env_id, source):
    kwargs = {} if source is None else {"observation_source": source}
    sync, batched = _pair(env_id, 4, **kwargs)
    rng = np.random.default_rng(0)

    def act(_obs, t):
        return np.zeros((4, 3)) if t % 4 == 0 else rng.uniform(-1, 1, (4, 3))

    ended = _run_pair(sync, batched, seed=7, steps=450, act=act)
    assert ended >= 4  # every sub-env went through at least one autoreset
    sync.close()
    batched.close()


@pytest.mark.parametrize("env_id", ["CaptureBench/Paper-v1", "CaptureBench/Grasp-v1"])
def test_an_analytic_controller_captures_as_in_single_envs(env_id):
    """Captures, capture times and the bound at the episode's end (incremental IK on Paper, and
    on Grasp, whose captures need eq. 20 to hold for 0.3 s)."""
    sync, batched = _pair(env_id, 3)
    single = gym.make(env_id)
    agents = [make_agent("incremental_ik", single) for _ in range(3)]
    successes = []

    def act(obs, t):
        return np.stack([agent.predict(o)[0] for agent, o in zip(agents, obs, strict=True)])

    original_step = sync.step

    def step(actions):
        out = original_step(actions)
        successes.extend(out[4]["is_success"][out[4]["_is_success"]].tolist())
        for agent, done in zip(agents, out[2] | out[3], strict=True):
            if done:
                agent.reset()
        return out

    sync.step = step
    _run_pair(sync, batched, seed=100, steps=400, act=act)
    assert sum(successes) >= 3
    single.close()


def test_seeding_reset_mask_and_autoreset_contract():
    env = CaptureVectorEnv(3, "paper")
    with pytest.raises(RuntimeError, match="before reset"):
        env.step(np.zeros((3, 3)))
    obs_a, _ = env.reset(seed=[5, 6, 7])
    obs_b, _ = CaptureVectorEnv(3, "paper").reset(seed=5)  # int s: s, s + 1, s + 2
    np.testing.assert_array_equal(obs_a, obs_b)
    assert env.observation_space.shape == (3, 16) and env.action_space.shape == (3, 3)
    assert obs_a in env.observation_space
    # reset_mask: only sub-env 1 starts again, from a new seed
    env.step(np.zeros((3, 3)))
    obs_c, info = env.reset(seed=[None, 9, None], options={"reset_mask": [False, True, False]})
    assert info["_time"].tolist() == [False, True, False]
    obs_9, _ = CaptureVectorEnv(3, "paper").reset(seed=[9, 9, 9])
    np.testing.assert_array_equal(obs_c[1], obs_9[1])
    with pytest.raises(ValueError, match=r"actions must have shape \(3, 3\); got shape \(2, 3\)"):
        env.step(np.zeros((2, 3)))
    with pytest.raises(
        ValueError, match=r"actions\[0, 0\] is nan; every entry must be a finite number"
    ):
        env.step(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="reward must be one of"):
        CaptureVectorEnv(2, "paper", reward="potential")
    with pytest.raises(ValueError, match="num_envs must be a positive integer"):
        CaptureVectorEnv(0, "paper")
    with pytest.raises(ValueError, match="does not render"):
        gym.make_vec("CaptureBench/Paper-v1", 2, render_mode="rgb_array")
    with pytest.raises(ValueError, match="vectorization_mode='sync'"):
        gym.make_vec("CaptureBench/Paper-v1", 2, reuse_target_side=False)
    obs_d, _ = env.reset(seed=np.array([5, 6, 7]))  # numpy seeds too
    np.testing.assert_array_equal(obs_d, obs_a)
    info = env.step(np.zeros((3, 3)))[4]
    assert info["_time"] is not info["_distance"]  # a mask per key, as SyncVectorEnv gives
    env.close()
    with pytest.raises(RuntimeError, match=r"after close\(\); the env is closed"):
        env.step(np.zeros((3, 3)))


def test_reachability_of_many_points_equals_one_by_one_and_the_scalar_reference():
    from references.scalar_kinematics import reachable as scalar_reachable

    points = np.random.default_rng(3).uniform(-1.0, 1.0, (5000, 3))
    reach = reachable(points)
    assert reach.tolist() == [bool(reachable(p)) for p in points] and 200 < reach.sum() < 4800
    assert reach.tolist() == [scalar_reachable(p) for p in points]
    assert reachable(points.reshape(50, 100, 3)).tolist() == reach.reshape(50, 100).tolist()


def test_joint_limits_and_collision_screen_agree_with_the_world():
    world = World(FEATURE_POINTS["non_coplanar"])
    from capture_bench.sim.kinematics import ArmSpec

    arm = ArmSpec()
    rng = np.random.default_rng(4)
    theta0 = rng.uniform(arm.joint_lower - 0.2, arm.joint_upper + 0.2, (300, 3))
    request = rng.uniform(-0.6, 0.6, (300, 3))
    dt = rng.uniform(0.03, 0.07, 300)
    after, clipped, saturated = limit_joint_increments(theta0, request, dt, arm)
    for i in range(300):
        step = apply_joint_increment(theta0[i], request[i], dt[i], arm)
        np.testing.assert_array_equal(after[i], step.theta)
        assert (clipped[i], saturated[i]) == (step.clipped, step.saturated)
    # The screen may send a clear pose to pybullet, never a colliding pose past it.
    theta = rng.uniform(arm.joint_lower - 0.6, arm.joint_upper + 0.6, (3000, 3))
    clear = clear_of_collisions(theta)
    collides = []
    for q in theta:
        world.set_joint_positions(q.tolist())
        collides.append(world.collision() is not None)
    collides = np.array(collides)
    assert collides.sum() > 300 and clear.sum() > 1000
    assert not np.any(clear & collides)
    world.close()


class _Counter:
    """A seed source: start, start + 1, ..."""

    def __init__(self, start: int) -> None:
        self.value = start - 1

    def next(self) -> int:
        self.value += 1
        return self.value


def test_seed_sources_seed_every_episode():
    """With ``set_episode_seeds``, episode k of sub-env i is the source's k-th seed's episode;
    an explicit seed plays once and the stream goes on; None restores gymnasium's rule."""
    env = CaptureVectorEnv(2, "paper")
    env.set_episode_seeds([_Counter(10), _Counter(20)])
    obs, _ = env.reset()
    assert env.episode_seeds == [10, 20]
    reference = CaptureVectorEnv(2, "paper")
    np.testing.assert_array_equal(obs, reference.reset(seed=[10, 20])[0])
    obs, _ = env.reset(seed=[5, None])
    assert env.episode_seeds == [5, 21]
    np.testing.assert_array_equal(obs, reference.reset(seed=[5, 21])[0])
    env.reset(options={"reset_mask": [True, False]})
    assert env.episode_seeds == [11, 21]
    env.set_episode_seeds([_Counter(30), _Counter(40)])  # what was recorded ahead is dropped
    env.reset()
    assert env.episode_seeds == [30, 40]
    env.set_episode_seeds(None)
    obs, _ = env.reset(seed=7)
    assert env.episode_seeds == [7, 8]
    np.testing.assert_array_equal(obs, reference.reset(seed=7)[0])
    env.reset()
    assert env.episode_seeds == [None, None]  # continuing each sub-env's generator
    with pytest.raises(ValueError, match="2 seed sources"):
        env.set_episode_seeds([_Counter(0)])
    env.close()
    reference.close()


class _Counting:
    """A seed source: start + 1, start + 2, ..."""

    def __init__(self, start: int) -> None:
        self.seed = start

    def next(self) -> int:
        self.seed += 1
        return self.seed


def _transitions(env: CaptureVectorEnv, steps: int, sources: bool = False) -> list[np.ndarray]:
    """Everything ``env`` returns over ``steps`` steps of random actions from ``reset(seed=3)``
    (or, with ``sources``, from seed sources as training uses them), across autoresets, as
    arrays (info's object arrays as their repr)."""
    rng = np.random.default_rng(5)
    n = env.num_envs
    if sources:
        env.set_episode_seeds([_Counting(100 * i) for i in range(n)])
    obs, info = env.reset(seed=None if sources else 3)
    out = [obs, *(np.asarray(info[key]) for key in sorted(info))]
    for t in range(steps):
        scale = 0.1 if (t // 25) % 2 else 1.0  # slow spells, so that some episodes capture
        obs, reward, terminated, truncated, info = env.step(scale * rng.uniform(-1, 1, (n, 3)))
        out += [obs, reward, terminated, truncated]
        for key in sorted(info):
            value = info[key]
            out.append(np.array(repr(value.tolist())) if value.dtype == object else value)
    return out


@pytest.mark.parametrize("scenario", ["paper", "noisy", "jitter", "grasp"])
def test_the_live_ekf_equals_the_recorded_full_horizon_bit_for_bit(scenario, monkeypatch):
    """The EKF that runs only as far as each episode is played (from row 1, or from row 3 after
    three recorded rows) gives every step exactly what the recording of every row to the time
    limit gave it (``LIVE_ESTIMATES_FROM = None``):
    observations, rewards, ends and info, across autoresets, with drop-outs and divergences
    (noisy) and episodes of different lengths (jitter)."""
    from capture_bench.engine import sides

    out = []
    for first_live_row in (1, 3, None):  # None: every row recorded, the reference
        monkeypatch.setattr(sides, "LIVE_ESTIMATES_FROM", first_live_row)
        env = CaptureVectorEnv(5, scenario)
        out.append(_transitions(env, 260))
        env.close()
    *lives, recorded = out
    for live in lives:
        assert len(live) == len(recorded)
        for i, (a, b) in enumerate(zip(live, recorded, strict=True)):
            np.testing.assert_array_equal(a, b, err_msg=f"value {i}")


def test_the_live_ekf_equals_the_recorded_one_with_many_sub_envs(monkeypatch):
    """64 sub-envs with seed sources, as training steps them: the recording's EKF then updates
    ~128 filters at once, where OpenBLAS splits a product's rows between threads (and rounds
    the last row of each odd share its own way); the live filter still gives the same floats."""
    from capture_bench.engine import sides

    out = []
    for first_live_row in (1, None):
        monkeypatch.setattr(sides, "LIVE_ESTIMATES_FROM", first_live_row)
        env = CaptureVectorEnv(64, "noisy")
        out.append(_transitions(env, 120, sources=True))
        env.close()
    for i, (a, b) in enumerate(zip(*out, strict=True)):
        np.testing.assert_array_equal(a, b, err_msg=f"value {i}")


# -- the single env is the vector env's N = 1 ---------------------------------------------------


def _assert_step_equal(single: tuple, vector: tuple, where: str) -> None:
    """One single-env step against sub-env 0 of a vector step: observation, reward, ends and
    every info entry (None against NaN), floats to rounding, the rest exactly."""
    obs, reward, terminated, truncated, info = single
    obs_v, reward_v, terminated_v, truncated_v, info_v = vector
    np.testing.assert_allclose(obs_v[0], obs, atol=1e-5, err_msg=where)
    assert reward_v[0] == pytest.approx(reward, rel=1e-7, abs=1e-9), where
    assert (terminated_v[0], truncated_v[0]) == (terminated, truncated), where
    reported = {k for k in info_v if not k.startswith("_") and info_v[f"_{k}"][0]}
    assert reported == set(info), where
    for key, value in info.items():
        got = info_v[key][0]
        if key in DISCRETE:
            assert got == value, (where, key)
        else:
            expected = np.nan if value is None else value
            np.testing.assert_allclose(
                got, expected, rtol=1e-6, atol=1e-8, err_msg=f"{where} {key}"
            )


@pytest.mark.parametrize("scenario", ["paper", "evasive", "grasp", "noisy"])
def test_the_single_env_equals_the_vector_env_of_one(scenario):
    """``CaptureEnv(reuse_target_side=True)`` stepped, and reset when its episode ends, against
    ``CaptureVectorEnv(1)`` with next-step autoreset, field for field: episodes that capture
    (incremental IK), collide (a swing into the floor), time out (small random moves), or lose
    the target (evasive)."""
    single = CaptureEnv(scenario, reuse_target_side=True)
    vector = CaptureVectorEnv(1, scenario)
    agent = make_agent("incremental_ik", single)
    rng = np.random.default_rng(0)
    obs, info = single.reset(seed=3)
    obs_v, info_v = vector.reset(seed=3)
    np.testing.assert_allclose(obs_v[0], obs, atol=1e-5)
    assert info == pytest.approx({k: info_v[k][0] for k in info})
    ends, episode, t = [], 0, 0
    while episode < 6:
        if episode % 3 == 0:
            action = agent.predict(obs)[0]
        elif episode % 3 == 1:
            action = np.array([1.0, -1.0, -1.0])  # into the floor
        else:
            action = 0.2 * rng.uniform(-1, 1, 3)
        step = single.step(action)
        _assert_step_equal(step, vector.step(np.asarray(action)[None]), f"{episode}/{t}")
        obs, t = step[0], t + 1
        if step[2] or step[3]:
            ends.append("capture" if step[4]["is_success"] else step[4]["failure"])
            obs, info = single.reset()  # the sub-env's next episode, from its generator
            obs_v, reward_v, terminated_v, truncated_v, info_v = vector.step(np.zeros((1, 3)))
            np.testing.assert_allclose(obs_v[0], obs, atol=1e-5)
            assert (reward_v[0], terminated_v[0], truncated_v[0]) == (0.0, False, False)
            assert info == pytest.approx({k: info_v[k][0] for k in info})
            episode, t = episode + 1, 0
            agent.reset()
    single.close()
    vector.close()
    assert "capture" in ends and "collision" in ends
    assert len(set(ends)) >= 3  # and timeouts, or the target lost or out of reach
    if scenario == "evasive":
        assert {"unreachable", "target_lost"} & set(ends)


# -- no autoreset: a batch of episodes, each played once to its end -----------------------------


def test_without_autoreset_sub_envs_play_their_seeds_and_ended_ones_stay_ended():
    """``autoreset_mode=DISABLED``: ``reset(seed=[s0, s1, s2])`` plays in sub-env i the single
    env's episode of seed s_i; episodes of different lengths (a capture, a collision, the time
    limit) end with the single env's last step, field for field; a step while some have ended
    leaves those as they are and steps the others; a masked reset with new seeds starts only
    those."""
    vector = gym.make_vec(
        "CaptureBench/Paper-v1", 3, vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.DISABLED,
    )  # fmt: skip
    assert vector.metadata["autoreset_mode"] == AutoresetMode.DISABLED
    singles = [CaptureEnv("paper", reuse_target_side=True) for _ in range(3)]
    agent = make_agent("incremental_ik", singles[0])
    seeds = [21, 22, 23]
    obs, _ = vector.reset(seed=seeds)
    single_obs = [env.reset(seed=s)[0] for env, s in zip(singles, seeds, strict=True)]
    np.testing.assert_allclose(obs, single_obs, atol=1e-5)
    ends: list[tuple[int, int, str]] = []  # (sub-env, length, how it ended)
    t = np.zeros(3, dtype=int)
    while not any(i == 2 for i, *_ in ends):  # until the longest, the waiting sub-env, ends
        actions = np.array([
            agent.predict(single_obs[0])[0],  # captures
            [1.0, -1.0, -1.0],  # swings into the floor
            np.zeros(3),  # waits for the time limit
        ])  # fmt: skip
        out = vector.step(actions)
        t += 1
        ended = []
        for i, env in enumerate(singles):
            step = env.step(actions[i])
            single_obs[i] = step[0]
            _assert_step_equal(step, tuple(_row(x, i) for x in out), f"sub-env {i} t {t[i]}")
            if step[2] or step[3]:
                ended.append(i)
                how = "capture" if step[4]["is_success"] else step[4]["failure"]
                ends.append((i, int(t[i]), how))
        if not ended:
            continue
        # a step leaves the ended sub-envs as they are (the others step: replayed below)
        frozen_obs, rewards, terminated, truncated, info = vector.step(actions)
        np.testing.assert_array_equal(frozen_obs[ended], out[0][ended])
        assert not rewards[ended].any() and not (terminated | truncated)[ended].any()
        assert not any(info[k][ended].any() for k in info if k.startswith("_"))
        for i in set(range(3)) - set(ended):
            step = singles[i].step(actions[i])
            single_obs[i] = step[0]
            t[i] += 1
            _assert_step_equal(
                step,
                tuple(_row(x, i) for x in (frozen_obs, rewards, terminated, truncated, info)),
                f"sub-env {i} t {t[i]}",
            )
            if step[2] or step[3]:
                ends.append(
                    (i, int(t[i]), "capture" if step[4]["is_success"] else step[4]["failure"])
                )
                ended.append(i)
        mask = np.zeros(3, dtype=bool)
        mask[ended] = True
        new = [s + 3 if m else None for s, m in zip(seeds, mask, strict=True)]  # unused: None
        obs, info = vector.reset(seed=new, options={"reset_mask": mask})
        assert info["_time"].tolist() == mask.tolist()
        for i in ended:
            seeds[i] += 3
            single_obs[i] = singles[i].reset(seed=seeds[i])[0]
            t[i] = 0
        agent.reset()
        np.testing.assert_allclose(obs, single_obs, atol=1e-5)  # the others are where they were
    for env in singles:
        env.close()
    vector.close()
    assert {how for i, _, how in ends if i == 0} == {"capture"}
    assert {how for i, _, how in ends if i == 1} == {"collision"}
    assert [(length, how) for i, length, how in ends if i == 2] == [(200, "timeout")]
    assert len(ends) >= 5 and len({length for _, length, _ in ends}) >= 3


def _row(value, i: int):
    """Sub-env i's part of a vector step's return, kept in the vector form (a batch of one)."""
    if isinstance(value, dict):
        return {k: v[i : i + 1] for k, v in value.items()}
    return value[i : i + 1]


def test_the_autoreset_mode_is_checked():
    with pytest.raises(ValueError, match=r"autoreset_mode must be one of .*NEXT_STEP"):
        CaptureVectorEnv(2, "paper", autoreset_mode=AutoresetMode.SAME_STEP)
    env = CaptureVectorEnv(2, "paper", autoreset_mode="Disabled")
    assert env.metadata["autoreset_mode"] == AutoresetMode.DISABLED
    assert CaptureVectorEnv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    env.close()
