"""The physical-limit bound against a brute-force scan and its own definition."""

import numpy as np
import pytest

from capture_bench import kinematics as k
from capture_bench.physical_limit import feasible_solutions, nearest_in_box, physical_limit
from capture_bench.scenarios import load_scenario
from capture_bench.target_motion import sample_trajectory

EPS = np.full(3, 1e-3)
ARGS = (k.HOME, k.JOINT_RATE_LIMITS, k.JOINT_LOWER, k.JOINT_UPPER, EPS)


def brute_force_onset(traj, horizon, step=1e-3):
    """Earliest time on a fine grid with an exact IK solution inside the reachable box."""
    times = np.arange(0.0, horizon, step)
    solutions = k.inverse_kinematics_batch(traj.position(times))
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
        start = np.clip(k.inverse_kinematics(goal), lo, hi)
        q = nearest_in_box(
            start,
            np.tile(goal, (len(start), 1)),
            np.tile(lo, (len(start), 1)),
            np.tile(hi, (len(start), 1)),
        )
        found = np.linalg.norm(k.forward_kinematics(q) - goal, axis=1).min()
        assert np.all((q >= lo - 1e-12) & (q <= hi + 1e-12))
        assert found <= best + 5e-5
