"""The pybullet world: floor, base column, the Table 1 arm and the target with its feature markers.

Frames and units (see ``docs/architecture.md``): global frame at the centre of joint 2, z up,
metres and radians; the floor is the plane ``z = -L0``. The arm is loaded from
``assets/arm.urdf`` with a fixed base; its link frames agree with
`capture_bench.sim.kinematics.forward_kinematics` and
`capture_bench.sim.kinematics.elbow_position` to pybullet's single-precision geometry (~1e-7
m; pybullet 3.2.7 stores link offsets and joint rotations as 32-bit floats, so 1e-9 m is not
attainable).

The arm is driven **kinematically**, as in the paper: joint angles are set, not simulated.
`limit_joint_increments` is the rule that keeps them within ``|delta_theta_i| <= theta_dot_max_i
* dt`` and the joint limits whatever an agent asks; the world sets the angles it is given. The
target has no collision shape: capture is a geometric test done elsewhere; the target is only
drawn.

``World`` imports nothing from gymnasium. It owns one ``BulletClient``; ``close()`` is safe twice.

The URDF's collision model, the joint limits and the renderer all act on the one
``BulletClient`` this class owns; the collision screen and the trace drawing live in their own
modules (`capture_bench.sim.collision_screen`, `capture_bench.sim.traces`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import NoReturn, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench._quiet import quiet_c_output

with quiet_c_output():  # pybullet prints its build time on import
    import pybullet
    from pybullet_utils.bullet_client import BulletClient

from capture_bench.sim.kinematics import L0, L1, L2, ArmSpec, FloatArray
from capture_bench.sim.markers import create_marked_target
from capture_bench.sim.rotations import quaternion_xyzw
from capture_bench.sim.traces import draw_polyline, project_points

ARM_URDF = Path(__file__).parent / "assets" / "arm.urdf"

# pybullet link indices of the arm (see assets/arm.urdf); the turret (0) has no collision shape.
BASE_COLUMN, UPPER_ARM, FOREARM, END_EFFECTOR = -1, 1, 2, 3

RENDER_MODES = (None, "rgb_array", "human")
SATURATION_FRACTION = 0.999  # a joint "saturates" when it runs at >= this share of its rate limit

_MARKER_RADIUS = 0.012  # m
_MARKER_COLOURS = ((0.9, 0.1, 0.1, 1), (0.1, 0.75, 0.1, 1), (0.1, 0.3, 0.95, 1), (1, 0.85, 0.1, 1))
_TRACE_COLOURS = ((220, 40, 40), (40, 90, 230), (30, 160, 60), (230, 150, 20), (150, 50, 200))
# Third-person camera: looks at the middle of the workspace from the front-right, slightly above.
_CAMERA = {"target": (0.25, 0.0, 0.1), "distance": 1.9, "yaw": 50.0, "pitch": -22.0, "fov": 45.0}


class World:
    """Floor, base column, arm and target in a private pybullet client.

    Args:
        feature_points: the four feature points in the target frame, metres, shape (4, 3). They
            are drawn as coloured spheres (red, green, blue, yellow in that order).
        render_mode: ``None`` or ``"rgb_array"`` (headless ``DIRECT`` client) or ``"human"`` (a
            ``GUI`` window; needs a display).
        arm: the arm's published constants: the joints start at its home pose; the link lengths
            must be Table 1's (the URDF models that arm only). Default ``ArmSpec()``.
        marker_radius: None (default) for the target above; a radius in metres for the rendered
            camera's target instead (`capture_bench.sim.markers.create_marked_target`:
            spheres of that radius in the detector's colours, red, green, cyan, magenta, and a
            grey block clear of them).

    Collision model (`collision`): capsules for the upper arm (radius 0.025 m), the forearm
    (0.025 m, offset 0.06 m sideways along the joint axes) and the wrist bracket at the tip
    (0.02 m); a cylinder (radius 0.05 m) for the base column; the plane ``z = -L0`` for the floor.
    """

    def __init__(
        self,
        feature_points: ArrayLike,
        *,
        render_mode: str | None = None,
        arm: ArmSpec | None = None,
        marker_radius: float | None = None,
    ) -> None:
        arm = ArmSpec() if arm is None else arm
        if render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
        if not np.allclose(arm.link_lengths, (L0, L1, L2), rtol=0.0, atol=1e-12):
            raise ValueError(
                f"arm.link_lengths {arm.link_lengths} differ from Table 1 {(L0, L1, L2)}; "
                "assets/arm.urdf models the Table 1 arm only"
            )
        features = np.array(feature_points, dtype=float)
        if features.shape != (4, 3) or not np.all(np.isfinite(features)):
            raise ValueError(f"feature_points must be a finite (4, 3) array, got {features.shape}")
        self.render_mode = render_mode
        self.feature_points = features
        self._q = cast("tuple[float, float, float]", tuple(float(v) for v in arm.home))
        self._debug_items: dict[str, int] = {}  # trace name -> GUI debug item id

        mode = pybullet.GUI if render_mode == "human" else pybullet.DIRECT
        with quiet_c_output():  # pybullet's C side prints "argv[0]=" on connect
            self._bullet: BulletClient | None = BulletClient(connection_mode=mode)
        bullet = self._bullet
        if render_mode == "human":
            bullet.configureDebugVisualizer(bullet.COV_ENABLE_GUI, 0)
            bullet.resetDebugVisualizerCamera(
                _CAMERA["distance"], _CAMERA["yaw"], _CAMERA["pitch"], _CAMERA["target"]
            )
        self.floor = self._create_floor(bullet)
        self.arm = bullet.loadURDF(
            str(ARM_URDF),
            basePosition=(0.0, 0.0, 0.0),
            useFixedBase=True,
            flags=pybullet.URDF_USE_SELF_COLLISION | pybullet.URDF_USE_IMPLICIT_CYLINDER,
        )
        # Pairs that touch by construction: the column holds the floor and joint 2; the forearm
        # capsule's end overlaps the wrist bracket it carries.
        bullet.setCollisionFilterPair(self.floor, self.arm, -1, BASE_COLUMN, 0)
        bullet.setCollisionFilterPair(self.arm, self.arm, BASE_COLUMN, UPPER_ARM, 0)
        bullet.setCollisionFilterPair(self.arm, self.arm, FOREARM, END_EFFECTOR, 0)
        self.target = (
            self._create_target(bullet, features)
            if marker_radius is None
            else create_marked_target(bullet, features, marker_radius)
        )

        # Hot-path functions bound to this client once (each attribute read on the client goes
        # through BulletClient.__getattr__).
        self._reset_joints = bullet.resetJointStatesMultiDof
        self._reset_base = bullet.resetBasePositionAndOrientation
        self._detect = bullet.performCollisionDetection
        self._contacts = bullet.getContactPoints
        self._set_joints(self._q)

    @staticmethod
    def _create_floor(bullet: BulletClient) -> int:
        """Collision plane z = -L0 with a thin box (top face at z = -L0) to draw it."""
        plane = bullet.createCollisionShape(pybullet.GEOM_PLANE)
        half = (1.5, 1.5, 0.005)
        visual = bullet.createVisualShape(
            pybullet.GEOM_BOX,
            halfExtents=half,
            rgbaColor=(0.78, 0.8, 0.76, 1),
            visualFramePosition=(0.0, 0.0, -half[2]),
        )
        return bullet.createMultiBody(0.0, plane, visual, basePosition=(0.0, 0.0, -L0))

    @staticmethod
    def _create_target(bullet: BulletClient, features: FloatArray) -> int:
        """Target body (frame origin = capture point): a block over the features, 4 markers."""
        lo, hi = features.min(axis=0), features.max(axis=0)
        half = np.maximum((hi - lo) / 2.0 - 0.5 * _MARKER_RADIUS, 0.005)
        shapes = [pybullet.GEOM_BOX, pybullet.GEOM_SPHERE] + [pybullet.GEOM_SPHERE] * 4
        visual = bullet.createVisualShapeArray(
            shapeTypes=shapes,
            radii=[0.0, 0.008] + [_MARKER_RADIUS] * 4,
            halfExtents=[half.tolist()] + [[0.0, 0.0, 0.0]] * 5,
            visualFramePositions=[((lo + hi) / 2.0).tolist(), [0.0, 0.0, 0.0]] + features.tolist(),
        )
        # No collision shape, and an empty collision group/mask: the target never collides.
        target = bullet.createMultiBody(0.0, -1, visual, basePosition=(0.0, 0.0, 0.0))
        bullet.setCollisionFilterGroupMask(target, -1, 0, 0)
        colours = [(0.55, 0.55, 0.6, 1), (0.05, 0.05, 0.05, 1), *_MARKER_COLOURS]
        for index, colour in enumerate(colours):
            bullet.changeVisualShape(target, -1, shapeIndex=index, rgbaColor=colour)
        return target

    @property
    def theta(self) -> FloatArray:
        """Current joint angles, rad, shape (3,) (a copy; the world's own record, not a query)."""
        return np.array(self._q)

    def _set_joints(self, q: tuple[float, float, float]) -> None:
        # targetValues must be a list: a tuple there crashes pybullet 3.2.7 (segfault).
        self._reset_joints(self.arm, [0, 1, 2], [[q[0]], [q[1]], [q[2]]])
        self._q = q

    def reset(
        self, theta: ArrayLike, target_position: ArrayLike, target_rotation: ArrayLike
    ) -> None:
        """Set the joints and the target pose instantly.

        Args:
            theta: joint angles, rad, shape (3,). Not clipped to the joint limits (tests use
                poses outside them); `limit_joint_increments` never moves a joint further out.
            target_position: capture point in the global frame, metres, shape (3,).
            target_rotation: R_gt, target axes as columns in global coordinates, shape (3, 3).
        """
        q = np.asarray(theta, dtype=float)
        if q.shape != (3,) or not np.all(np.isfinite(q)):
            raise ValueError(f"theta must be a finite (3,) array, got {q!r}")
        self._set_joints((float(q[0]), float(q[1]), float(q[2])))
        self.set_target_pose(target_position, target_rotation)

    def set_joint_positions(self, theta: Sequence[float]) -> None:
        """Set the three joints to angles computed elsewhere, rad, as they are: the caller has
        applied the rate and joint limits (`limit_joint_increments`)."""
        self._set_joints((float(theta[0]), float(theta[1]), float(theta[2])))

    def set_target_pose(self, position: ArrayLike, rotation: ArrayLike) -> None:
        """Place the target: capture point at ``position`` (global, metres, (3,)), orientation
        ``rotation`` (R_gt, orthonormal, (3, 3); not checked, for speed)."""
        p = (
            position.tolist()
            if isinstance(position, np.ndarray)
            else list(cast("Iterable[float]", position))
        )
        r = (
            rotation.tolist()
            if isinstance(rotation, np.ndarray)
            else cast("Sequence[Sequence[float]]", rotation)
        )
        if len(p) != 3 or len(r) != 3:
            raise ValueError("position must have shape (3,) and rotation (3, 3)")
        self._reset_base(self.target, p, quaternion_xyzw(r))

    def collision(self) -> str | None:
        """Which collision the arm is in now: ``"floor"``, ``"base"``, ``"self"`` or ``None``.

        * ``"floor"``: upper arm, forearm or wrist touches the floor plane.
        * ``"base"``: forearm or wrist touches the base column. The upper arm meets the column at
          joint 2 by construction, so that pair is off (the upper arm cannot reach the column
          otherwise; with theta2 in [20, 100] deg it points upwards).
        * ``"self"``: the wrist bracket touches the upper arm (the forearm tube is offset sideways
          and never can). Only possible when the arm folds to theta3 < ~-84 deg, outside limits.

        Touching (penetration depth >= 0) counts. With several, the first in that order is
        returned. Uses one ``performCollisionDetection`` and one ``getContactPoints``.
        """
        self._detect()
        found: set[str] = set()
        for contact in self._contacts(self.arm):
            if contact[8] > 0.0:  # contactDistance: manifold points inside the margin only
                continue
            body_a, body_b, link_a, link_b = contact[1], contact[2], contact[3], contact[4]
            if self.floor in (body_a, body_b):
                return "floor"
            if body_a == body_b == self.arm:
                found.add("base" if BASE_COLUMN in (link_a, link_b) else "self")
        for name in ("base", "self"):
            if name in found:
                return name
        return None

    def end_effector_position_pybullet(self) -> FloatArray:
        """End-effector (forearm tip) frame origin from pybullet, global, metres, shape (3,)."""
        state = self._client().getLinkState(self.arm, END_EFFECTOR, computeForwardKinematics=True)
        return np.array(state[4])  # worldLinkFramePosition

    def elbow_position_pybullet(self) -> FloatArray:
        """Elbow (joint 3) frame origin from pybullet, global, metres, shape (3,)."""
        state = self._client().getLinkState(self.arm, FOREARM, computeForwardKinematics=True)
        return np.array(state[4])  # worldLinkFramePosition

    def target_pose_pybullet(self) -> tuple[FloatArray, FloatArray]:
        """Target pose from pybullet: capture point (global, metres, (3,)) and R_gt (3, 3)."""
        bullet = self._client()
        position, quaternion = bullet.getBasePositionAndOrientation(self.target)
        rotation = np.reshape(bullet.getMatrixFromQuaternion(quaternion), (3, 3))
        return np.array(position), rotation

    @property
    def client(self) -> BulletClient:
        """The world's pybullet client (to render it; the world still owns and closes it)."""
        return self._client()

    def _client(self) -> BulletClient:
        if self._bullet is None:
            raise RuntimeError("the World is closed")
        return self._bullet

    def render(
        self,
        width: int = 640,
        height: int = 480,
        traces: Mapping[str, ArrayLike] | None = None,
    ) -> np.ndarray:
        """Third-person image of the world, with traces drawn over it.

        Args:
            width, height: image size, pixels.
            traces: named polylines in the global frame, metres, each shape (N, 3) (e.g. the
                target's and the end-effector's past positions). Colours follow insertion order:
                red, blue, green, orange, purple. In ``"human"`` mode they are also shown in the
                GUI window as debug points.

        Returns:
            RGB image, shape (height, width, 3), uint8 (TinyRenderer; works headless).
        """
        bullet = self._client()
        view = bullet.computeViewMatrixFromYawPitchRoll(
            _CAMERA["target"], _CAMERA["distance"], _CAMERA["yaw"], _CAMERA["pitch"], 0.0, 2
        )
        proj = bullet.computeProjectionMatrixFOV(_CAMERA["fov"], width / height, 0.05, 20.0)
        _, _, rgba, _, _ = bullet.getCameraImage(
            width, height, view, proj, renderer=pybullet.ER_TINY_RENDERER
        )
        image = np.array(np.reshape(rgba, (height, width, 4))[..., :3], dtype=np.uint8)
        transform = np.reshape(proj, (4, 4)).T @ np.reshape(view, (4, 4)).T  # column-major in
        for index, (name, points) in enumerate((traces or {}).items()):
            colour = _TRACE_COLOURS[index % len(_TRACE_COLOURS)]
            pts = np.asarray(points, dtype=float).reshape(-1, 3)
            draw_polyline(image, project_points(pts, transform, width, height), colour)
            if self.render_mode == "human":
                self._draw_debug_trace(bullet, name, pts, colour)
        return image

    def _draw_debug_trace(
        self, bullet: BulletClient, name: str, points: FloatArray, colour: tuple[int, ...]
    ) -> None:
        """``"human"`` mode: show a trace in the GUI window as debug points (replacing the last)."""
        bullet.removeUserDebugItem(self._debug_items.pop(name, -1))
        if len(points) == 0:  # pybullet fails on an empty point list
            return
        rgb = [[c / 255.0 for c in colour]] * len(points)
        self._debug_items[name] = bullet.addUserDebugPoints(points.tolist(), rgb, 3.0)

    def close(self) -> None:
        """Disconnect the client. Safe to call more than once."""
        if self._bullet is not None:
            bullet, self._bullet = self._bullet, None
            bullet.disconnect()  # BulletClient marks itself disconnected, so __del__ won't retry
            # The cached calls carry the client id, which pybullet reuses for the next connection:
            # make them fail rather than reach another World's simulation.
            self._reset_joints = self._reset_base = self._detect = self._contacts = _closed

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def limit_joint_increments(
    theta: FloatArray,
    delta_theta: FloatArray,
    dt: FloatArray,
    arm: ArmSpec,
) -> tuple[FloatArray, NDArray[np.bool_], NDArray[np.bool_]]:
    """The arm's rate and joint limits applied to M requested increments.

    Each ``|delta_i|`` is clipped to ``theta_dot_max_i * dt``, then the result to the joint limits
    (a joint already outside them, set by `World.reset`, may not move further out).

    Args:
        theta: joint angles before the step, rad, (M, 3).
        delta_theta: requested increments, rad, (M, 3), finite.
        dt: the real duration of each arm's step, s, (M,), > 0.
        arm: the rate and joint limits.

    Returns:
        ``(theta_after (M, 3), clipped (M,), saturated (M,))``: the joint angles after the step;
        whether a limit (rate or joint) reduced the request on some joint; whether some joint ran
        at >= ``SATURATION_FRACTION`` of its rate limit ``theta_dot_max_i * dt``.
    """
    step_max = arm.joint_rate_limits * dt[:, None]
    step = np.minimum(np.maximum(delta_theta, -step_max), step_max)  # to ±step_max (> 0)
    unclipped = theta + step
    lowest, highest = np.minimum(arm.joint_lower, theta), np.maximum(arm.joint_upper, theta)
    after = np.minimum(np.maximum(unclipped, lowest), highest)
    clipped = np.any((step != delta_theta) | (after != unclipped), axis=1)
    saturated = np.any(np.abs(after - theta) >= SATURATION_FRACTION * step_max, axis=1)
    return np.asarray(after, dtype=float), clipped, saturated


def _closed(*args: object, **kwargs: object) -> NoReturn:
    raise RuntimeError("the World is closed")
