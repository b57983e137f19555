"""The task statistics of training episodes (capture_bench/training/common/episode_stats.py), on
hand-built ``info`` dicts, and against the leaderboard's per-episode record on a real episode."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capture_bench.task.step_rule import END_INFO_KEYS, FAILURES, INFO_KEYS
from capture_bench.training.common.episode_stats import (
    EpisodeStats,
    EpisodeTracker,
    episode_stats,
    finite_items,
    summarize,
)

NAN = math.nan


def step(error=NAN, **end):
    """One step's info (the keys the statistics read), the episode's last if ``end`` is given."""
    info = {"is_success": False, "failure": None, "capture_time": None,
            "estimate_position_error": error}  # fmt: skip
    info.update(end)
    return info


# Four episodes: captured (bound 0.2 s), collision, timeout without any estimate, captured with
# no finite bound. Each: its steps' infos and its return.
EPISODES = [
    ([step(), step(0.02), step(0.04, is_success=True, capture_time=0.3, physical_limit_time=0.2)],
     [1.0, 1.0, 5.0]),
    ([step(0.1, failure="collision", physical_limit_time=math.inf)], [-3.0]),
    ([step(), step(failure="timeout", physical_limit_time=0.5)], [-1.0, -1.0]),
    ([step(0.3), step(0.5, is_success=True, capture_time=0.5, physical_limit_time=math.inf)],
     [0.0, 2.0]),
]  # fmt: skip


def stats_of(episode):
    infos, rewards = episode
    return episode_stats(
        infos[-1], [i["estimate_position_error"] for i in infos], float(np.sum(rewards))
    )


def test_the_keys_read_are_the_task_info_keys():
    read = {"is_success", "failure", "capture_time", "estimate_position_error"}
    assert read <= set(INFO_KEYS) and "physical_limit_time" in END_INFO_KEYS


def test_episode_statistics_by_hand():
    captured, collision, timeout, unbounded = map(stats_of, EPISODES)
    assert captured == EpisodeStats(True, None, 0.3, 0.2, pytest.approx(1.5), 0.03, 7.0)
    assert collision.failure == "collision" and not collision.captured
    assert math.isnan(collision.capture_time) and math.isnan(collision.ratio_to_limit)
    assert collision.estimate_position_error_m == 0.1 and collision.physical_limit_time == math.inf
    assert timeout.failure == "timeout" and math.isnan(timeout.estimate_position_error_m)
    assert unbounded.captured and unbounded.capture_time == 0.5
    assert math.isnan(unbounded.ratio_to_limit)  # no finite bound: no ratio
    assert unbounded.estimate_position_error_m == pytest.approx(0.4)


def test_summary_by_hand():
    result = summarize([stats_of(e) for e in EPISODES])
    assert result["capture_rate"] == 0.5
    assert result["median_capture_time"] == pytest.approx(0.4)  # median of 0.3 and 0.5
    assert result["median_ratio_to_limit"] == pytest.approx(1.5)  # the one finite ratio
    # scores: 1 / 1.5 for the bounded capture, 1 for the unbounded one, 0 for each failure
    assert result["mean_score"] == pytest.approx((1 / 1.5 + 1.0) / 4)
    assert result["failure/collision"] == 0.25 and result["failure/timeout"] == 0.25
    assert result["failure/target_lost"] == 0 and result["failure/unreachable"] == 0
    assert result["estimate_position_error_m"] == pytest.approx((0.03 + 0.1 + 0.4) / 3)
    assert result["mean_reward"] == pytest.approx((7 - 3 - 2 + 2) / 4)
    assert {f"failure/{r}" for r in FAILURES} <= set(result)


def test_nothing_to_compute_on_is_nan_and_left_out_of_the_log():
    assert all(math.isnan(v) for v in summarize([]).values())
    assert finite_items(summarize([])) == {}
    failed = summarize([stats_of(EPISODES[2])])  # a timeout without an estimate
    assert math.isnan(failed["median_capture_time"]) and math.isnan(failed["median_ratio_to_limit"])
    logged = finite_items(failed)
    assert failed["mean_score"] == 0.0  # a failure scores 0
    assert set(logged) == {
        "capture_rate",
        "mean_score",
        "mean_reward",
        *(f"failure/{r}" for r in FAILURES),
    }
    assert "mean_reward" not in summarize([episode_stats(EPISODES[0][0][-1], [])])  # no rewards


def test_tracker_interleaving_two_envs_gives_each_episode_its_own_steps():
    """Env 0 plays episodes 0 then 1, env 1 plays 2 then 3, stepped together."""
    tracker = EpisodeTracker(2)
    queues = [EPISODES[0][0] + EPISODES[1][0], EPISODES[2][0] + EPISODES[3][0]]
    rewards = [EPISODES[0][1] + EPISODES[1][1], EPISODES[2][1] + EPISODES[3][1]]
    ended: list[tuple[int, EpisodeStats]] = []
    for t in range(4):
        infos = [queues[0][t], queues[1][t]]
        dones = ["physical_limit_time" in info for info in infos]
        ended += tracker.step(infos, dones, [rewards[0][t], rewards[1][t]])
    by_env = {0: [stats_of(EPISODES[0]), stats_of(EPISODES[1])],
              1: [stats_of(EPISODES[2]), stats_of(EPISODES[3])]}  # fmt: skip
    for env in (0, 1):
        got = [s for i, s in ended if i == env]
        assert len(got) == 2
        for a, b in zip(got, by_env[env]):
            for field in EpisodeStats.__dataclass_fields__:
                x, y = getattr(a, field), getattr(b, field)
                assert x == y or (x != x and y != y), field  # equal or both NaN


def test_a_real_episode_agrees_with_the_leaderboard_record():
    """The capture, failure, capture time and ratio of a real episode are the leaderboard's
    (capture_bench.evaluation.running.rollout.run_episode) on the same seed."""
    from capture_bench.agents.baselines import Hold, PurePursuit
    from capture_bench.envs.capture_env import CaptureEnv
    from capture_bench.evaluation.running.rollout import run_episode

    env = CaptureEnv("paper")
    outcomes = []
    try:
        seed = env.scenario.validation_seeds[2]
        for agent in (PurePursuit(env.description), Hold(env.description)):
            record, _ = run_episode(env, agent, agent_name="a", scenario="paper", seed=seed)
            obs, _ = env.reset(seed=seed)
            tracker, done, ended = EpisodeTracker(1), False, []
            while not done:
                obs, reward, terminated, truncated, info = env.step(agent.predict(obs)[0])
                done = terminated or truncated
                ended = tracker.step([info], [done], [reward])
            (_, stats), = ended  # fmt: skip
            outcomes.append(record.outcome)
            assert stats.captured == (record.outcome == "captured")
            assert (stats.failure or "") == record.failure
            np.testing.assert_equal(
                [stats.capture_time, stats.ratio_to_limit, stats.physical_limit_time],
                [record.capture_time, record.ratio, record.physical_limit_time],
            )
    finally:
        env.close()
    assert outcomes == ["captured", "failed"]  # both kinds of episode were compared
