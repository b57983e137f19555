"""The physical-limit bound against a brute-force scan and its own definition."""

import numpy as np
import pytest

from capture_bench.sim import kinematics as k
from capture_bench.sim.target_motion import sample_trajectory
from capture_bench.task.physical_limit import (
    CHUNK,
    REFINE,
    REFINE_PASSES,
    distance_lower_bound,
    feasible_solutions,
    first_feasible,
    nearest_in_box,
    physical_limit,
    physical_limits,
    refine_times,
)
from capture_bench.task.scenarios import load_scenario

EPS = np.full(3, 1e-3)
ARGS = (k.HOME, k.JOINT_RATE_LIMITS, k.JOINT_LOWER, k.JOINT_UPPER, EPS)


def brute_force_onset(traj, horizon, step=1e-3):
    """Earliest time on a fine grid with an exact IK solution inside the reachable box."""
    times = np.arange(0.0, horizon, step)
    solutions = k.inverse_kinematics(traj.position(times))
    lo = np.maximum(k.JOINT_LOWER, k.HOME - np.outer(times, k.JOINT_RATE_LIMITS))[:, None]
    hi = np.minimum(k.JOINT_UPPER, k.HOME + np.outer(times, k.JOINT_RATE_LIMITS))[:, None]
    ok = np.all((solutions >= lo) & (solutions <= hi), axis=2).any(axis=1)
    return times[np.argmax(ok)] if ok.any() else np.inf


@pytest.mark.parametrize("name", ["paper", "circular", "tumbling"])
def test_bound_matches_a_brute_force_scan(name):
    cfg = load_scenario(name).target
    for seed in range(5):
        traj = sample_trajectory(
            cfg, np.random.default_rng(seed), k.forward_kinematics(k.HOME), 10.0
        )
        limit = physical_limit(traj.position, *ARGS, horizon=10.0, period=0.05)
        exact = brute_force_onset(traj, 10.0)
        if np.isinf(exact):
            continue
        # The tolerance (a 1.7 mm sphere) can only make the bound earlier, by about
        # |epsilon| / (speed at which the reachable set's edge closes on the target).
        assert exact - 0.04 <= limit.time <= exact + 1e-3
        # The returned joint vector reaches the target at that time from inside the box.
        miss = k.forward_kinematics(limit.theta) - traj.position(limit.time)
        assert np.linalg.norm(miss) < np.linalg.norm(EPS)
        assert np.all(np.abs(limit.theta - k.HOME) <= k.JOINT_RATE_LIMITS * limit.time + 1e-9)
        assert k.within_limits(limit.theta)


def test_a_target_sitting_on_the_end_effector_gives_zero_and_an_unreachable_one_infinity():
    home_ee = k.forward_kinematics(k.HOME)
    assert physical_limit(lambda t: np.tile(home_ee, (len(t), 1)), *ARGS, 10.0, 0.05).time == 0.0
    far = np.array([3.0, 0.0, 0.0])
    limit = physical_limit(lambda t: np.tile(far, (len(t), 1)), *ARGS, 10.0, 0.05)
    assert limit.time == np.inf and limit.theta is None


def test_tolerance_admits_points_just_outside_the_box():
    # A point 0.5 mm beyond what joint 2 can reach at t is feasible with epsilon = 1 mm, not 0.1 mm.
    t = 0.2  # joint 2 then moves 4.7 deg, well inside its limit
    q = k.HOME + np.array([0.0, k.JOINT_RATE_LIMITS[1] * t, 0.0])
    direction = k.jacobian(q)[:, 1] / np.linalg.norm(k.jacobian(q)[:, 1])
    target = (k.forward_kinematics(q) + 5e-4 * direction)[None]
    ok, theta = feasible_solutions(target, np.array([t]), *ARGS)
    assert ok[0]
    assert not feasible_solutions(target, np.array([t]), *ARGS[:-1], np.full(3, 1e-4))[0][0]


def test_nearest_in_box_against_a_brute_force_grid():
    """The local search finds (to 0.05 mm) the best point of a dense grid of the box."""
    rng = np.random.default_rng(4)
    for _ in range(10):
        centre = rng.uniform(k.JOINT_LOWER + 0.2, k.JOINT_UPPER - 0.2)
        half = np.array([0.05, 0.02, 0.02])
        lo, hi = centre - half, centre + half
        goal = k.forward_kinematics(centre + rng.uniform(-2, 2, 3) * half)  # often outside the box
        axes = [np.linspace(lo[i], hi[i], 41) for i in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        best = np.linalg.norm(k.forward_kinematics(grid) - goal, axis=1).min()
        solutions = k.inverse_kinematics(goal)
        start = np.clip(solutions[~np.isnan(solutions[:, 0])], lo, hi)
        q = nearest_in_box(
            start,
            np.tile(goal, (len(start), 1)),
            np.tile(lo, (len(start), 1)),
            np.tile(hi, (len(start), 1)),
        )
        found = np.linalg.norm(k.forward_kinematics(q) - goal, axis=1).min()
        assert np.all((q >= lo - 1e-12) & (q <= hi + 1e-12))
        assert found <= best + 5e-5


# -- many episodes at once --------------------------------------------------------------------


def reference_physical_limit(target_position, horizon, period, travel_time=None, eps=EPS):
    """The single-episode search written out on `feasible_solutions` (every row evaluated)."""

    def check(times):
        travel = times if travel_time is None else travel_time(times)
        return feasible_solutions(target_position(times), travel, *ARGS[:-1], eps)

    n_grid = int(np.floor(horizon / period + 1e-9)) + 1
    for start in range(0, n_grid, CHUNK):
        times = np.arange(start, min(start + CHUNK, n_grid), dtype=np.float64) * period
        ok, theta = check(times)
        if not ok.any():
            continue
        k = int(np.argmax(ok))
        if start + k == 0:
            return 0.0, theta[0]
        t_lo, t_hi, best = times[k] - period, times[k], theta[k]
        for _ in range(REFINE_PASSES):
            fine = np.linspace(t_lo, t_hi, REFINE + 1)[1:]
            ok_fine, theta_fine = check(fine)
            j = int(np.argmax(ok_fine))
            if ok_fine[j]:
                t_lo, t_hi, best = (fine[j - 1] if j else t_lo), fine[j], theta_fine[j]
        return float(t_hi), best
    return np.inf, None


def slow_start(t):
    """A travel time: the joints move at 70 % of their rate for the first second."""
    return np.where(t < 1.0, 0.7 * t, t - 0.3)


def mixed_episodes():
    """(target_position, horizon, travel_time) of episodes of every kind."""
    home_ee = k.forward_kinematics(k.HOME)
    far = np.array([3.0, 0.0, 0.0])
    out = [
        (lambda t: np.tile(home_ee, (len(t), 1)), 10.0, None),  # feasible at t = 0
        (lambda t: np.tile(far, (len(t), 1)), 10.0, None),  # never: inf
        (lambda t: np.tile(far, (len(t), 1)), 0.12, slow_start),  # never, short horizon
    ]
    for i, name in enumerate(["paper", "circular", "tumbling", "drift", "evasive"]):
        cfg = load_scenario(name).target
        for seed in range(3):
            traj = sample_trajectory(cfg, np.random.default_rng(seed), home_ee, 10.0)
            horizon = [10.0, 2.37, 0.61][seed]  # the shortest ends before most onsets
            out.append((traj.position, horizon, slow_start if (i + seed) % 2 else None))
    traj = sample_trajectory(load_scenario("paper").target, np.random.default_rng(0), home_ee, 10.0)
    out.append((traj.position, 10.0, lambda t: 0.3 * t))  # slow joints: past the first chunk
    return out


def batch(episodes, period=0.05, eps=EPS):
    return physical_limits(
        [e[0] for e in episodes],
        *ARGS[:-1],
        eps,
        horizons=[e[1] for e in episodes],
        period=period,
        travel_times=[e[2] for e in episodes],
    )


def assert_same(got, time, theta):
    assert got.time == time
    if theta is None:
        assert got.theta is None
    else:
        np.testing.assert_array_equal(got.theta, theta)


def test_batch_equals_episode_by_episode_calls_and_the_full_evaluation():
    episodes = mixed_episodes()
    limits = batch(episodes)
    assert len(limits) == len(episodes)
    times = [limit.time for limit in limits]
    assert times[0] == 0.0 and np.isinf(times[1]) and np.isinf(times[2])
    assert sum(0.0 < t < np.inf for t in times) >= 6  # onsets found by refinement
    assert sum(np.isinf(t) for t in times) >= 4  # incl. onsets past a short horizon
    assert CHUNK * 0.05 < times[-1] < np.inf
    for (position, horizon, travel), got in zip(episodes, limits):
        single = physical_limit(position, *ARGS, horizon=horizon, period=0.05, travel_time=travel)
        assert_same(got, single.time, single.theta)
        assert_same(got, *reference_physical_limit(position, horizon, 0.05, travel))
    # The order of the episodes in the batch changes nothing.
    for got, again in zip(limits, batch(episodes[::-1])[::-1]):
        assert_same(got, again.time, again.theta)


def test_batch_of_one_and_of_none():
    (position, horizon, travel) = mixed_episodes()[4]
    (got,) = batch([(position, horizon, travel)])
    assert 0.0 < got.time < np.inf
    single = physical_limit(position, *ARGS, horizon=horizon, period=0.05, travel_time=travel)
    assert_same(got, single.time, single.theta)
    assert batch([]) == []
    assert physical_limits([], *ARGS, horizons=[], period=0.05) == []
    with pytest.raises(ValueError, match="horizons"):
        physical_limits([position], *ARGS, horizons=[1.0, 2.0], period=0.05)
    with pytest.raises(ValueError, match="travel_times"):
        physical_limits([position], *ARGS, horizons=[1.0], period=0.05, travel_times=[])


def test_first_feasible_row_agrees_with_feasible_solutions():
    """The shortcut search gives every segment's first feasible row and theta as evaluated in full,
    for tolerances that make the local search decide (1.7 mm) or never admit anything (0)."""
    rng = np.random.default_rng(7)
    cfg = load_scenario("tumbling").target
    home_ee = k.forward_kinematics(k.HOME)
    for eps in (EPS, np.full(3, 5e-3), np.zeros(3)):
        targets, times, lengths = [], [], []
        for seed in range(12):
            traj = sample_trajectory(cfg, np.random.default_rng(seed), home_ee, 10.0)
            t = np.sort(rng.uniform(0.0, 3.0, rng.integers(1, 40)))
            targets.append(traj.position(t))
            times.append(t)
            lengths.append(t.size)
        offsets = np.concatenate(([0], np.cumsum(lengths)))
        targets, times = np.concatenate(targets), np.concatenate(times)
        ok, theta = feasible_solutions(targets, times, *ARGS[:-1], eps)
        first, first_theta = first_feasible(targets, times, offsets, *ARGS[:-1], eps)
        for s in range(len(lengths)):
            part = ok[offsets[s] : offsets[s + 1]]
            if part.any():
                row = offsets[s] + int(np.argmax(part))
                assert first[s] == row
                np.testing.assert_array_equal(first_theta[s], theta[row])
            else:
                assert first[s] == len(targets)


def test_distance_lower_bound_never_exceeds_the_distance_to_a_dense_grid_of_the_box():
    rng = np.random.default_rng(3)
    worst = -np.inf
    for _ in range(60):
        centre = rng.uniform(k.JOINT_LOWER, k.JOINT_UPPER)
        half = rng.uniform(0.002, 0.3, 3) * np.array([rng.choice([0.05, 3.0]), 1.0, 1.0])
        lo = np.maximum(k.JOINT_LOWER, centre - half)
        hi = np.minimum(k.JOINT_UPPER, centre + half)
        goals = k.forward_kinematics(centre + rng.normal(0.0, 0.3, (10, 3)))
        goals += rng.normal(0.0, rng.choice([0.0, 0.02]), goals.shape)
        axes = [np.linspace(lo[i], hi[i], 21) for i in range(3)]
        grid = k.forward_kinematics(np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3))
        nearest = np.linalg.norm(grid[None] - goals[:, None], axis=2).min(axis=1)
        bound = distance_lower_bound(
            goals,
            k.inverse_kinematics(goals),
            np.tile(lo, (10, 1)),
            np.tile(hi, (10, 1)),
            np.inf,
        )
        assert np.all(bound <= nearest + 1e-12)
        worst = max(worst, np.max(bound / np.maximum(nearest, 1e-9)))
    assert worst > 0.95  # and it is not vacuous


def test_nearest_in_box_rows_do_not_depend_on_the_rest_of_the_batch():
    rng = np.random.default_rng(5)
    lo = np.tile(k.HOME - 0.05, (40, 1))
    hi = np.tile(k.HOME + 0.05, (40, 1))
    goal = k.forward_kinematics(k.HOME + rng.uniform(-0.2, 0.2, (40, 3)))
    start = np.clip(k.HOME + rng.uniform(-0.2, 0.2, (40, 3)), lo, hi)
    together = nearest_in_box(start, goal, lo, hi)
    for i in range(40):
        alone = nearest_in_box(start[i : i + 1], goal[i : i + 1], lo[i : i + 1], hi[i : i + 1])
        np.testing.assert_array_equal(alone[0], together[i])


def test_refine_times_are_those_of_linspace_bit_for_bit():
    rng = np.random.default_rng(2)
    t_lo = np.concatenate((rng.uniform(0.0, 10.0, 500), [0.0, 1e-300, 3.0]))
    t_hi = t_lo + np.concatenate((rng.uniform(0.0, 0.05, 500) ** 3, [0.05, 1e-300, 0.0]))
    got = refine_times(t_lo, t_hi)
    for i in range(t_lo.size):
        np.testing.assert_array_equal(got[i], np.linspace(t_lo[i], t_hi[i], REFINE + 1)[1:])
