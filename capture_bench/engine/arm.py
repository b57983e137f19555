"""The arm's side of a step, for any number of episodes: `ArmSide`.

An agent's request moves each arm within its rate and joint limits
(`capture_bench.sim.world.limit_joint_increments`, the one rule of those limits), the end
effector follows by the analytic kinematics (`capture_bench.sim.kinematics.forward_kinematics`,
eq. 8), and pybullet answers the collision test only for the poses that the geometric screen
(`capture_bench.sim.collision_screen.clear_of_collisions`) cannot clear (a few asked poses go to
pybullet directly: same answers, fewer calls). One pybullet `World` answers every episode's
query in turn and, in a rendered env, shows the one episode.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sim import kinematics
from capture_bench.sim.collision_screen import clear_of_collisions
from capture_bench.sim.kinematics import ArmPose, ArmSpec, FloatArray
from capture_bench.sim.world import World, limit_joint_increments

__all__ = ["ArmSide"]

# Fewer asked rows than this go to pybullet unscreened: a query per pose costs less than a call
# of the screen, whose cost is per call at any M (``benchmarks/bench_world.py`` times both:
# ``collision`` and ``ArmSide.collides``); the screen never clears a colliding pose, so the
# answers are the same either way.
SCREEN_FROM = 3


class ArmSide:
    """How M arms move and whether they collide, with one pybullet `World` for the queries.

    Args:
        features: the target's four feature points in its frame, metres, (4, 3) (the world draws
            them).
        arm: the arm's rate and joint limits (a task's ``description.arm``).
        render_mode: the world's (`World`): ``None``, ``"rgb_array"`` or ``"human"``.
    """

    def __init__(self, features: ArrayLike, arm: ArmSpec, render_mode: str | None = None) -> None:
        self.arm = arm
        self.world = World(features, render_mode=render_mode)

    def move(
        self, theta0: FloatArray, request: FloatArray, dt: FloatArray
    ) -> tuple[FloatArray, ArmPose, NDArray[np.bool_], NDArray[np.bool_]]:
        """M arms at ``theta0`` (M, 3), rad, asked for the increments ``request`` (M, 3), rad,
        over steps of ``dt`` (M,), s.

        Returns:
            ``(theta, pose, clipped, saturated)``: the joint angles after the step (M, 3), rad,
            within the rate and joint limits; the arm there (`ArmPose`: X_E, eq. 8, and the
            trigonometry its velocity reuses); whether a limit reduced the request (M,); whether
            some joint ran at its rate limit (M,) (`limit_joint_increments`).
        """
        theta, clipped, saturated = limit_joint_increments(theta0, request, dt, self.arm)
        return theta, kinematics.arm_pose(theta), clipped, saturated

    def collides(self, theta: FloatArray, ask: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Whether each arm at ``theta`` (M, 3), rad, is in a collision of `World.collision`,
        for the rows ``ask`` (M,) asks (False elsewhere): pybullet is asked only where the screen
        cannot clear the pose (every asked pose below ``SCREEN_FROM`` of them). The world's
        joints are left at the last pose asked."""
        hit = np.zeros(len(theta), dtype=bool)
        world = self.world
        asked = np.flatnonzero(ask)
        if asked.size >= SCREEN_FROM:
            asked = asked[~clear_of_collisions(theta[asked])]
        for j in asked.tolist():
            world.set_joint_positions(theta[j].tolist())
            hit[j] = world.collision() is not None
        return hit

    def close(self) -> None:
        """Disconnect the world; safe twice."""
        self.world.close()
