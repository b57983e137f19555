"""The rendered camera in an episode: frames of the whole scene, the arm included, each rendered
once per seed where the arm cannot reach it.

A rendered frame shows the arm, so the target's side of an episode depends on the agent's
actions: a frame in which the arm hides a marker differs from one in which it does not. What the
arm can change is known without rendering: an arm link can only hide a marker whose image its own
image comes near (`obstacles_may_hide`, each link's
bounding box from pybullet, a margin of ``MARGIN_PX``). Everything else the detector reads (the
markers' pixels; the windows, which depend on the markers alone) is the same with the arm or
without it. So `RenderedSceneCamera` detects frame k of a seed

* **with the arm**, rendered now, where a link may hide a marker at any of the frame's sub-frame
  instants (or where the episode has no ``target_only`` store: the reference path, every frame
  rendered with the arm);
* **without it** otherwise: the target-only detection of frame k, rendered once (the arm moved far
  out of view) and kept in the episode's ``target_only``, a store shared by every episode of that
  seed (`capture_bench.engine.cache.EpisodeCache.scene_frames`): the leaderboard plays every
  agent on the same seeds, and the first one renders what the others reuse.

Both give the same detections for a frame the arm cannot reach (``tests/test_scene_camera.py``
plays episodes both ways and compares them frame by frame). The random stream is the sensor's
(`RenderedCamera`): one key per episode at
`reset`, one drop-out uniform per frame, whatever is rendered.

An episode's state is the `SceneEpisode` that `RenderedSceneCamera.reset` returns and each
`RenderedSceneCamera.capture_scene` takes: episodes interleaved on one camera (the batched env's
sub-envs share one pybullet world) each see the frames they would see alone.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from capture_bench.sensing.camera import CameraModel, Frame
from capture_bench.sensing.detector import Detections
from capture_bench.sensing.occlusion import MARGIN_PX, obstacles_may_hide
from capture_bench.sensing.pixels import pixel_of, sphere_image
from capture_bench.sensing.rendered_sensor import (
    PoseAt,
    RenderedCamera,
    RenderSettings,
    SceneEpisode,
    ThetaAt,
)
from capture_bench.sim.target_motion import FEATURE_POINTS, TargetTrajectory

FloatArray = NDArray[np.float64]
#: Where the arm goes while the target alone is rendered: far below the floor, out of every view.
AWAY = (0.0, 0.0, -1000.0)
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=float)


class RenderedSceneCamera(RenderedCamera):
    """A `RenderedCamera` that takes an episode's frames (``capture_scene``, the live
    target side's call) and reuses target-only detections where the arm cannot reach.

    Attributes:
        renders: frames rendered with the arm / without it / reused, since construction, over
            every episode (counts).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.renders = {"with_arm": 0, "target_only": 0, "reused": 0}
        client = self._world.client
        self._links = list(range(-1, client.getNumJoints(self._world.arm)))

    @classmethod
    def for_scenario(cls, scenario: Any, windowed: bool = True) -> RenderedSceneCamera:
        """The camera of a scenario with ``camera.mode: rendered`` (its pose, intrinsics,
        drop-out, latency, rendering, lens and calibration error keys)."""
        cam = scenario.camera
        model = cam.model()
        light = tuple(float(v) for v in cam.light_direction)
        settings = RenderSettings(
            marker_radius=cam.marker_radius,
            target_block=cam.target_block,
            light_direction=light if any(light) else None,
            light_intensity=cam.light_intensity,
            image_noise=cam.image_noise,
            exposure_s=cam.exposure,
            psf_sigma=cam.psf_sigma,
            windowed=windowed,
        )
        features = FEATURE_POINTS[scenario.target.feature_points]
        spread = cam.calibration_spread()
        return cls(model, features, settings, cam.dropout, cam.latency_frames, spread)

    def reset(
        self,
        rng: np.random.Generator | None = None,
        target_only: dict[int, Detections] | None = None,
    ) -> SceneEpisode:
        """A new episode's state (`RenderedCamera.reset`: the noise key's one draw from
        ``rng``) whose frames the arm cannot reach are read from and kept in ``target_only``
        (frame index -> the detections of the target alone, the seed's store); None: every
        frame rendered with the arm."""
        episode = super().reset(rng)
        episode.target_only = target_only
        return episode

    def capture_scene(
        self,
        state: SceneEpisode,
        k: int,
        time: float,
        trajectory: TargetTrajectory,
        arm_at: ThetaAt,
        rng: np.random.Generator,
    ) -> Frame | None:
        """Frame k of the episode ``state``, taken at ``time`` (s) of the target on
        ``trajectory`` with the arm at ``arm_at(t)``: `RenderedCamera.capture` (drop-out,
        latency)."""

        def pose_at(t: float) -> tuple[FloatArray, FloatArray]:
            return trajectory.position(t), trajectory.rotation(t)

        return self.capture(state, pose_at, time, arm_at, rng, k)

    def detect(
        self,
        pose_at: PoseAt,
        time: float,
        theta_at: ThetaAt,
        frame_index: int,
        episode: SceneEpisode | None = None,
    ) -> Detections:
        """The markers found in frame ``frame_index``: rendered with the arm where it may hide
        one (or without ``episode`` or its ``target_only`` store), else the target-only
        detection (module docstring)."""
        store = None if episode is None else episode.target_only
        if store is None or self.arm_may_hide(pose_at, time, theta_at, self.true_model(episode)):
            self.renders["with_arm"] += 1
            return super().detect(pose_at, time, theta_at, frame_index, episode)
        found = store.get(frame_index)
        if found is None:
            self.renders["target_only"] += 1
            with self._arm_away():
                found = super().detect(pose_at, time, theta_at, frame_index, episode)
            store[frame_index] = found
        else:
            self.renders["reused"] += 1
        return found

    def arm_may_hide(
        self,
        pose_at: PoseAt,
        time: float,
        theta_at: ThetaAt,
        model: CameraModel | None = None,
    ) -> bool:
        """Whether a link of the arm may hide a marker at any sub-frame instant of the image
        ``model`` (default: `model`) takes at ``time`` (conservative: each link's axis-aligned
        bounding box)."""
        radius = self.settings.marker_radius
        model = self.model if model is None else model
        margin = MARGIN_PX + 2 * self.settings.psf_radius  # blur: what reaches the markers' band
        instants = self.instants(pose_at, time)
        # A blurred image (optics, or sub-frames averaged) mixes a marker's edge with what lies
        # behind it: a link there counts too.
        behind = self.settings.psf_sigma > 0.0 or len(instants) > 1
        for t in instants:
            position, rotation = (np.asarray(v, dtype=float) for v in pose_at(float(t)))
            centres = position + self.features @ rotation.T
            boxes = self.link_boxes(theta_at(float(t)))
            # A first screen, all links at once: a link whose image's bounding rectangle stays
            # clear of every marker's image (plus the margin) cannot hide one.
            cam = model.to_camera(np.concatenate(boxes))
            if not np.all(model.in_front(cam)):
                return True
            pixels = pixel_of(cam, model).reshape(len(boxes), -1, 2)
            image = sphere_image(model.to_camera(centres), radius, model)
            reach = (image.semi_major + margin)[None, :, None]
            low, high = pixels.min(axis=1)[:, None, :], pixels.max(axis=1)[:, None, :]
            near = ((image.centre >= low - reach) & (image.centre <= high + reach)).all(axis=2)
            if not near.any():
                continue
            close = [box for box, hit in zip(boxes, near.any(axis=1), strict=True) if hit]
            if obstacles_may_hide(model, centres, radius, close, margin, behind).any():
                return True
        return False

    def link_boxes(self, theta: FloatArray) -> list[FloatArray]:
        """The 8 corners of each arm link's bounding box (pybullet's AABB) at joint angles
        ``theta``, global, metres: one (8, 3) array per link."""
        world = self._world
        world.set_joint_positions(np.asarray(theta, dtype=float))
        aabb = world.client.getAABB
        boxes = []
        for link in self._links:
            low, high = (np.asarray(v, dtype=float) for v in aabb(world.arm, link))
            boxes.append(low + _CORNERS * (high - low))
        return boxes

    def view(
        self,
        theta: FloatArray,
        position: FloatArray,
        rotation: FloatArray,
        size: tuple[int, int],
        detections: Detections | None = None,
        estimate: FloatArray | None = None,
        model: CameraModel | None = None,
    ) -> NDArray[np.uint8]:
        """What this camera sees, scaled to ``size`` (width, height, pixels; the sensor's aspect
        is kept by the caller), with the markers found drawn over it (a green ring on each found
        centroid, a red cross where a missing marker's eq. 2 projection falls) and the estimated
        capture point (a yellow cross, eq. 2 of ``estimate``, global, m).

        Args:
            theta: the arm's joint angles, rad, (3,).
            position, rotation: the target's capture point (global, m) and R_gt.
            size: the image's (width, height), pixels.
            detections: the markers found (full-sensor pixels), or None for none drawn.
            estimate: the estimated capture point, global, m, or None.
            model: the pinhole that took the image (an episode's `true_model`); None: `model`.
        """
        import cv2

        from capture_bench.sensing.pixels import image_plane_to_pixel
        from capture_bench.sensing.render_camera import render_frame

        model = self.model if model is None else model
        width, height = int(size[0]), int(size[1])
        scale = model.resolution[0] / width
        small = CameraModel(
            model.position,
            model.rotation,
            focal_length=model.focal_length,
            pixel_pitch=model.pixel_pitch * scale,
            resolution=(width, height),
        )
        world = self._world
        world.set_joint_positions(np.asarray(theta, dtype=float))
        world.set_target_pose(np.asarray(position, dtype=float), np.asarray(rotation, dtype=float))
        image = np.ascontiguousarray(render_frame(world.client, small, None, self._lighting))
        if detections is not None:
            centres = position + self.features @ np.asarray(rotation).T
            truth = image_plane_to_pixel(model.project(model.to_camera(centres)), model)
            for i, found in enumerate(detections.found.tolist()):
                if found:
                    u, v = (detections.pixels[i] + 0.5) / scale - 0.5
                    cv2.circle(image, (round(u), round(v)), 6, (0, 200, 0), 1, cv2.LINE_8)
                elif np.isfinite(truth[i]).all():
                    u, v = (truth[i] + 0.5) / scale - 0.5
                    _cross(image, u, v, (220, 0, 0))
        if estimate is not None and np.isfinite(estimate).all():
            cam = model.to_camera(np.asarray(estimate, dtype=float)[None])
            if model.in_front(cam).all():
                u, v = (image_plane_to_pixel(model.project(cam), model)[0] + 0.5) / scale - 0.5
                _cross(image, u, v, (230, 180, 0))
        return image

    @contextlib.contextmanager
    def _arm_away(self) -> Iterator[None]:
        """The arm moved out of view (`AWAY`) for the duration."""
        client, arm = self._world.client, self._world.arm
        # pybullet places a base by its centre of mass: put back exactly the pose it reports
        home, orientation = client.getBasePositionAndOrientation(arm)
        client.resetBasePositionAndOrientation(arm, AWAY, orientation)
        try:
            yield
        finally:
            client.resetBasePositionAndOrientation(arm, home, orientation)


def joint_path(theta0: FloatArray, theta1: FloatArray, t0: float, t1: float) -> ThetaAt:
    """The joints during a step: linear from ``theta0`` at ``t0`` to ``theta1`` at ``t1``, s
    (the joints move at constant rates within a step), held at either end outside it."""
    start, delta, span = np.array(theta0, dtype=float), np.asarray(theta1) - theta0, t1 - t0

    def at(t: float) -> FloatArray:
        s = 1.0 if span <= 0.0 else min(max((t - t0) / span, 0.0), 1.0)
        return start + s * delta

    return at


def _cross(image: NDArray[np.uint8], u: float, v: float, colour: tuple[int, int, int]) -> None:
    """A small diagonal cross centred on pixel (u, v), drawn in place."""
    import cv2

    a, b = round(u), round(v)
    cv2.line(image, (a - 4, b - 4), (a + 4, b + 4), colour, 1, cv2.LINE_8)
    cv2.line(image, (a - 4, b + 4), (a + 4, b - 4), colour, 1, cv2.LINE_8)
