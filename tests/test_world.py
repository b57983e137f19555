"""Tests of the pybullet world (URDF vs analytic kinematics, collisions, client ownership and
rendering), of the rate and joint limits and of the arm side that uses both."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from references.joint_limits import apply_joint_increment

from capture_bench.engine.arm import ArmSide
from capture_bench.sim.kinematics import (
    HOME,
    JOINT_LOWER,
    JOINT_RATE_LIMITS,
    JOINT_UPPER,
    L0,
    L1,
    L2,
    ArmSpec,
    elbow_position,
    forward_kinematics,
    within_limits,
)
from capture_bench.sim.rotations import axis_angle_to_matrix
from capture_bench.sim.world import World, limit_joint_increments

FEATURES = np.array([(0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (0.0, 0.1, 0.0), (0.0, 0.0, 0.05)])
DT = 0.05
# pybullet 3.2.7 stores link offsets and joint rotations in 32-bit floats (0.454025 m becomes
# 0.454025000334 m), so its link frames match the analytic FK to ~5e-8 m, not 1e-9 m.
FK_TOL = 5e-7  # m
FOREARM_RADIUS = 0.025  # m, the forearm capsule in assets/arm.urdf
TARGET_AWAY = np.array([0.3, 0.3, 0.3])


@pytest.fixture
def world():
    w = World(FEATURES)
    yield w
    w.close()


def _deg(*angles: float) -> np.ndarray:
    return np.radians(angles)


def test_home_end_effector_matches_paper(world):
    world.reset(HOME, TARGET_AWAY, np.eye(3))
    np.testing.assert_allclose(
        world.end_effector_position_pybullet(), [0.4445, 0, 0.454025], atol=FK_TOL
    )
    np.testing.assert_allclose(world.elbow_position_pybullet(), [0, 0, 0.454025], atol=FK_TOL)


def test_pybullet_link_frames_match_analytic_fk(world):
    rng = np.random.default_rng(0)
    worst = 0.0
    for theta in rng.uniform(JOINT_LOWER, JOINT_UPPER, (50, 3)):
        world.reset(theta, TARGET_AWAY, np.eye(3))
        ee_error = world.end_effector_position_pybullet() - forward_kinematics(theta)
        elbow_error = world.elbow_position_pybullet() - elbow_position(theta)
        worst = max(worst, np.abs(ee_error).max(), np.abs(elbow_error).max())
    assert worst < FK_TOL


def _limit(theta, delta, dt: float = DT):
    """`limit_joint_increments` for one arm: (theta after (3,), clipped, saturated)."""
    after, clipped, saturated = limit_joint_increments(
        np.array([theta], dtype=float), np.array([delta], dtype=float), np.array([dt]), ArmSpec()
    )
    return after[0], bool(clipped[0]), bool(saturated[0])


def test_huge_request_moves_each_joint_exactly_its_rate_limit():
    theta, clipped, saturated = _limit(HOME, [100.0, 100.0, -100.0])
    expected = JOINT_RATE_LIMITS * DT * np.array([1.0, 1.0, -1.0])
    np.testing.assert_allclose(theta - HOME, expected, rtol=0, atol=1e-12)
    assert clipped and saturated and within_limits(theta)


def test_rate_limit_scales_with_the_actual_dt():
    theta, _, _ = _limit(HOME, [-9.0, -9.0, 9.0], 0.1)
    np.testing.assert_allclose(
        theta - HOME, JOINT_RATE_LIMITS * 0.1 * np.array([-1, -1, 1]), rtol=0, atol=1e-12
    )


def test_small_request_is_applied_unchanged():
    delta = 0.5 * JOINT_RATE_LIMITS * DT * np.array([1.0, -1.0, 0.3])
    theta, clipped, saturated = _limit(HOME, delta)
    np.testing.assert_array_equal(theta, HOME + delta)
    assert not clipped and not saturated


def test_request_at_exactly_the_rate_limit_saturates_without_clipping():
    _, clipped, saturated = _limit(HOME, np.array([0.0, 0.0, 1.0]) * JOINT_RATE_LIMITS * DT)
    assert saturated and not clipped


def test_joint_limit_clips_and_flags():
    start = np.array([0.0, JOINT_UPPER[1] - 0.005, 0.0])
    theta, clipped, saturated = _limit(start, [0.0, 1.0, 0.0])
    assert theta[1] == JOINT_UPPER[1]
    assert theta[1] - start[1] == pytest.approx(0.005, abs=1e-12)
    assert clipped and not saturated
    again, clipped, _ = _limit(theta, [0.0, 0.01, 0.0])  # push on the limit
    assert again[1] == theta[1] and clipped


def test_joint_outside_limits_never_moves_further_out_nor_jumps_in():
    start = _deg(0, 20, -85)  # theta3 below its -70 deg limit, set directly
    out, clipped, _ = _limit(start, [0.0, 0.0, -0.01])
    assert out[2] == start[2] and clipped
    back, _, _ = _limit(start, [0.0, 0.0, 0.01])
    assert back[2] - start[2] == pytest.approx(0.01, abs=1e-15)


def test_limits_equal_the_scalar_reference_bit_for_bit():
    rng = np.random.default_rng(5)
    theta0 = rng.uniform(JOINT_LOWER - 0.2, JOINT_UPPER + 0.2, (500, 3))
    request = rng.uniform(-0.6, 0.6, (500, 3))
    request[::7] = JOINT_RATE_LIMITS * 0.05 * np.array([1.0, -1.0, 1.0])  # exactly at the rate
    dt = rng.uniform(0.03, 0.07, 500)
    dt[::7] = 0.05
    after, clipped, saturated = limit_joint_increments(theta0, request, dt, ArmSpec())
    for i in range(500):
        step = apply_joint_increment(theta0[i], request[i], dt[i])
        np.testing.assert_array_equal(after[i], step.theta)
        assert (clipped[i], saturated[i]) == (step.clipped, step.saturated)
    assert 50 < clipped.sum() < 500 and saturated.sum() > 50


def test_arm_side_moves_by_the_limits_and_forward_kinematics():
    arm_side = ArmSide(FEATURES, ArmSpec())
    try:
        rng = np.random.default_rng(6)
        theta0 = rng.uniform(JOINT_LOWER, JOINT_UPPER, (40, 3))
        request = rng.uniform(-0.3, 0.3, (40, 3))
        dt = np.full(40, DT)
        theta, pose, clipped, saturated = arm_side.move(theta0, request, dt)
        expected = limit_joint_increments(theta0, request, dt, ArmSpec())
        np.testing.assert_array_equal(theta, expected[0])
        np.testing.assert_array_equal(clipped, expected[1])
        np.testing.assert_array_equal(saturated, expected[2])
        np.testing.assert_array_equal(pose.x_e, forward_kinematics(theta))
        # Collisions: pybullet's answer on the rows asked, False elsewhere.
        # home, then the floor, base and self collisions of test_collision_poses, one not asked
        poses = np.array([HOME, _deg(0, 20, -20), _deg(0, 45, -83), _deg(0, 20, -95), HOME])
        ask = np.array([True, True, True, True, False])
        poses[4] = _deg(0, 20, -20)
        world = arm_side.world
        truth = []
        for q in poses:
            world.set_joint_positions(q.tolist())
            truth.append(world.collision() is not None)
        assert truth == [False, True, True, True, True]
        np.testing.assert_array_equal(arm_side.collides(poses, ask), np.array(truth) & ask)
    finally:
        arm_side.close()
        arm_side.close()  # safe twice


def test_theta_is_a_copy(world):
    world.reset(HOME, TARGET_AWAY, np.eye(3))
    world.theta[0] = 1.0
    np.testing.assert_array_equal(world.theta, HOME)


def test_constructor_validates_its_arguments():
    with pytest.raises(ValueError, match="feature_points"):
        World(FEATURES[:3])
    with pytest.raises(ValueError, match="render_mode"):
        World(FEATURES, render_mode="video")
    with pytest.raises(ValueError, match="Table 1"):
        World(FEATURES, arm=ArmSpec(link_lengths=(L0, 0.5, L2)))


@pytest.mark.parametrize(
    "degrees, expected, in_limits",
    [
        ((0, 90, 0), None, True),  # home
        ((30, 60, 10), None, True),
        ((0, 20, -20), "floor", True),  # forearm straight down from a low elbow, tip at z = -0.29
        ((0, 45, -83), "base", False),  # folded back: the tip reaches into the column
        ((0, 20, -95), "self", False),  # folded past the upper arm: the wrist crosses it
    ],
)
def test_collision_poses(world, degrees, expected, in_limits):
    theta = _deg(*degrees)
    assert bool(within_limits(theta)) == in_limits
    world.reset(theta, TARGET_AWAY, np.eye(3))
    assert world.collision() == expected


@pytest.mark.parametrize("gap, expected", [(0.002, None), (-0.002, "floor")])
def test_floor_contact_starts_at_the_forearm_surface(world, gap, expected):
    # Forearm tip at z = -L0 + radius + gap: the capsule clears (gap > 0) or touches the floor.
    theta2 = np.radians(20.0)
    z_tip = -L0 + FOREARM_RADIUS + gap
    theta3 = np.arccos((L1 * np.sin(theta2) - z_tip) / L2) - theta2
    theta = np.array([0.5, theta2, theta3])
    assert within_limits(theta)
    world.reset(theta, TARGET_AWAY, np.eye(3))
    assert world.collision() == expected


@pytest.mark.parametrize("degrees, expected", [((0, 90, 0), None), ((0, 20, -20), "floor")])
def test_target_on_the_end_effector_or_the_floor_never_collides(world, degrees, expected):
    theta = _deg(*degrees)
    world.reset(theta, forward_kinematics(theta), np.eye(3))  # capture point on the tip
    assert world.collision() == expected
    world.set_target_pose([0.3, 0.0, -L0], np.eye(3))  # capture point on the floor
    assert world.collision() == expected


def test_target_pose_round_trips_through_pybullet(world):
    rng = np.random.default_rng(1)
    rotations = [axis_angle_to_matrix(rng.normal(size=3), a) for a in rng.uniform(0, np.pi, 20)]
    rotations += [np.diag(d) for d in ([1, -1, -1], [-1, 1, -1], [-1, -1, 1])]  # 180 deg turns
    for rotation in rotations:
        position = rng.uniform(-0.5, 0.5, 3)
        world.set_target_pose(position, rotation)
        got_position, got_rotation = world.target_pose_pybullet()
        np.testing.assert_allclose(got_position, position, atol=1e-6)
        np.testing.assert_allclose(got_rotation, rotation, atol=1e-6)


def test_close_is_idempotent_and_closed_world_refuses_work():
    w = World(FEATURES)
    w.close()
    w.close()
    with pytest.raises(RuntimeError):
        w.collision()
    with pytest.raises(RuntimeError):
        w.end_effector_position_pybullet()


def test_context_manager_closes():
    with World(FEATURES) as w:
        w.reset(HOME, TARGET_AWAY, np.eye(3))
    with pytest.raises(RuntimeError):
        w.render(32, 24)


def test_two_worlds_do_not_interfere():
    with World(FEATURES) as a, World(FEATURES) as b:
        a.reset(_deg(0, 20, -20), TARGET_AWAY, np.eye(3))
        b.reset(_deg(40, 70, 10), TARGET_AWAY, np.eye(3))
        assert a.collision() == "floor" and b.collision() is None
        np.testing.assert_allclose(
            a.end_effector_position_pybullet(), forward_kinematics(_deg(0, 20, -20)), atol=FK_TOL
        )
        np.testing.assert_allclose(
            b.end_effector_position_pybullet(), forward_kinematics(_deg(40, 70, 10)), atol=FK_TOL
        )
        a.close()
        with World(FEATURES) as c:  # may reuse a's client id; a must not reach it
            c.reset(HOME, TARGET_AWAY, np.eye(3))
            with pytest.raises(RuntimeError):
                a.collision()
            assert c.collision() is None and b.collision() is None


def test_render_returns_a_non_blank_image_with_traces(world):
    world.reset(HOME, forward_kinematics(HOME) + [0.05, 0.1, -0.1], np.eye(3))
    plain = world.render(160, 120)
    assert plain.shape == (120, 160, 3) and plain.dtype == np.uint8
    assert plain.std() > 10.0  # not a blank frame
    line = np.c_[np.linspace(0.1, 0.6, 40), np.linspace(-0.3, 0.3, 40), np.full(40, 0.3)]
    traced = world.render(160, 120, traces={"target": line, "end_effector": line[:1] + 0.05})
    assert traced.shape == plain.shape
    red = np.all(traced == (220, 40, 40), axis=-1)
    assert red.sum() > 50  # the target trace crosses the view
    assert np.array_equal(world.render(160, 120, traces={"empty": np.zeros((0, 3))}), plain)


def test_human_mode_trace_drawing_runs_headless(world):
    # The GUI path (debug points) cannot open a window here; in DIRECT its calls are no-ops.
    world.render_mode = "human"
    line = np.c_[np.linspace(0.1, 0.6, 5), np.zeros(5), np.full(5, 0.3)]
    for n in (5, 2, 0):
        assert world.render(32, 24, traces={"target": line[:n]}).shape == (24, 32, 3)


def test_bench_world_main_runs(capsys):
    path = Path(__file__).parents[1] / "benchmarks" / "bench_world.py"
    spec = importlib.util.spec_from_file_location("bench_world", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--steps", "20", "--repeats", "1"]) == 0
    assert "full_step" in capsys.readouterr().out
