"""The image an agent sees with ``observation_source="pixels"``: the eye-to-hand camera's view of a
crop around the workspace, rendered directly at the image's size.

**The crop.** A whole-frame 84 x 84 image of the shipped 1280 x 960 camera would show the target's
5 mm markers as less than a pixel, so the image is a square-pixel crop of the sensor, ``s width``
x ``s height`` sensor pixels with s the largest *odd* whole number for which the crop's longer side
is at most ``CROP_SIDE`` times the sensor's shorter side, centred on the sensor pixel
``CROP_CENTRE`` (fractions of its width and height), moved inside the sensor where it would cross
an edge (`crop_window`). For the shipped camera and the default 84 x 84 image: s = 11, the
924 x 924 sensor pixels ``u`` 255-1178, ``v`` 18-941; one image pixel spans ~6.2 mm at the
camera's 1.2 m from the workspace. The centre sits right of the sensor's because the target's
markers lie on the capture point's +x side. Measured on 1,000 training seeds of ``paper`` and of
``grasp`` (their targets start alike), the capture point starts at least 10 sensor pixels inside
the crop in 98.9 % of episodes and stays there for the first 3 s (about a capture's time) in
98.5 %; a centred crop (``u`` 178-1101) keeps 95.5 % and 94.3 %.

**The scene.** The world of `World` with ``marker_radius``: the
floor, the base column, the arm at its current joint angles, and the target at its true pose drawn
as the rendered camera's target (`capture_bench.sim.markers.create_marked_target`): its grey
block and four sphere markers of ``IMAGE_MARKER_RADIUS`` = 10 mm (the scenario's 5 mm markers
would be under a pixel; the markers are what makes the target's orientation visible). Lit as the
scenario's camera keys say (``light_direction``, ``light_intensity``), no specular highlights, no
shadows. The image is the instant's: no sensor noise, no motion blur, no drop-out, no latency
(the estimator, which still runs for ``info``, keeps the scenario's).

**Sampling.** The crop is rendered by TinyRenderer at the image's size through the crop's own
frustum (`render_frame` with ``size``): image pixel
``(i, j)`` (row, column) shows the scene at the centre of the crop's full-density pixel
``(s i + s // 2, s j + s // 2)``, so the image is the full-density render of the crop
(`WorkspaceImager.full_density`) sampled at those pixels, but for pixels on a triangle's
edge to float32 precision (TinyRenderer rasterises each frustum on its own). Measured over random
arm and target poses: no pixel differed in 30 scenes at 84 x 84 (s = 11), nor in 8 at 64 x 64
(s = 13) or 84 x 64; at 36 x 36 (s = 25) one pixel of 1,296 differed in 2 of 8 scenes.
The image comes channel-first, ``(3, height, width)``, uint8 RGB, as SB3's CNN policies take it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.render_camera import (
    Lighting,
    Window,
    camera_image_request,
    check_window,
    render_frame,
)
from capture_bench.sim.world import World

IMAGE_SIZE = (84, 84)  # (width, height), pixels: the default image
CROP_CENTRE = (0.56, 0.5)  # the crop's centre, fractions of the sensor's width and height
CROP_SIDE = 0.9625  # the crop's longest side, share of the sensor's shorter side (924 of 960)
IMAGE_MARKER_RADIUS = 0.01  # m: the image's target markers

FloatArray = NDArray[np.float64]


def largest_crop_side(model: CameraModel) -> int:
    """The longest side a crop may have on ``model``'s sensor, pixels:
    ``round(CROP_SIDE * min(width, height))``."""
    return round(CROP_SIDE * min(model.resolution))


def check_image_size(size: Any, model: CameraModel) -> tuple[int, int]:
    """``size`` as ``(width, height)`` (None: `IMAGE_SIZE`), or ``ValueError`` saying what
    is valid: two whole numbers from 1 to `largest_crop_side` (924 for the shipped
    camera)."""
    largest = largest_crop_side(model)
    if size is None:
        size = IMAGE_SIZE
    try:
        width, height = size
    except (TypeError, ValueError):
        width = height = None
    if not all(
        isinstance(n, (int, np.integer)) and not isinstance(n, bool) and 1 <= n <= largest
        for n in (width, height)
    ):
        raise ValueError(
            f"image_size must be (width, height), two whole numbers from 1 to {largest} (the "
            f"largest crop of the {model.resolution[0]} x {model.resolution[1]} sensor); got "
            f"{size!r}"
        )
    return int(width), int(height)


def crop_scale(model: CameraModel, size: tuple[int, int]) -> int:
    """Sensor pixels per image pixel on a side, s: the largest odd whole number with
    ``s max(width, height) <= largest_crop_side(model)`` (11 for 84 x 84 on the shipped
    camera)."""
    width, height = check_image_size(size, model)
    s = largest_crop_side(model) // max(width, height)
    return s if s % 2 else s - 1


def crop_window(model: CameraModel, size: tuple[int, int]) -> Window:
    """The crop ``(u0, u1, v0, v1)``, sensor pixels: ``s width`` x ``s height`` centred on
    pixel ``CROP_CENTRE`` of the sensor (rounded; the top-left corner at ``centre - side // 2``),
    moved inside the sensor if it would cross an edge (module docstring)."""
    width, height = check_image_size(size, model)
    s = crop_scale(model, (width, height))
    sensor_w, sensor_h = model.resolution
    cu, cv = round(CROP_CENTRE[0] * sensor_w), round(CROP_CENTRE[1] * sensor_h)
    u0 = min(max(cu - s * width // 2, 0), sensor_w - s * width)
    v0 = min(max(cv - s * height // 2, 0), sensor_h - s * height)
    return check_window((u0, u0 + s * width, v0, v0 + s * height), model)


class WorkspaceImager:
    """Renders the pixel observation (module docstring) from a pybullet world of its own.

    Args:
        model: the eye-to-hand camera.
        features: the target's feature points (marker centres), target frame, m, (4, 3).
        size: the image's ``(width, height)``, pixels (`check_image_size`).
        lighting: the light; None for ``Lighting()`` (from the lens).
        marker_radius: the target's marker radius, m.

    Attributes:
        size: ``(width, height)``; scale: s; window: the crop ``(u0, u1, v0, v1)``, sensor pixels.
    """

    def __init__(
        self,
        model: CameraModel,
        features: ArrayLike,
        size: tuple[int, int] = IMAGE_SIZE,
        lighting: Lighting | None = None,
        marker_radius: float = IMAGE_MARKER_RADIUS,
    ) -> None:
        self.model = model
        self.size = check_image_size(size, model)
        self.scale = crop_scale(model, self.size)
        self.window = crop_window(model, self.size)
        self.lighting = Lighting() if lighting is None else lighting
        self._request = camera_image_request(model, self.window, self.lighting, size=self.size)
        self._world: World | None = World(features, marker_radius=marker_radius)

    def render(
        self,
        theta: ArrayLike,
        position: ArrayLike,
        rotation: ArrayLike,
        out: NDArray[np.uint8] | None = None,
    ) -> NDArray[np.uint8]:
        """The image of the arm at joint angles ``theta`` (rad, (3,)) and the target with its
        capture point at ``position`` (global, m, (3,)) and attitude ``rotation`` (R_gt, (3, 3)):
        uint8 RGB, ``(3, height, width)``, written into ``out`` if given."""
        world = self._open_world()
        world.set_joint_positions(np.asarray(theta, dtype=float).tolist())
        world.set_target_pose(position, rotation)
        width, height = self.size
        _, _, rgba, _, _ = world.client.getCameraImage(**self._request)
        rgb = np.reshape(rgba, (height, width, 4))[..., :3].transpose(2, 0, 1)
        if out is None:
            return np.ascontiguousarray(rgb, dtype=np.uint8)
        out[...] = rgb
        return out

    def render_batch(
        self, theta: ArrayLike, position: ArrayLike, rotation: ArrayLike
    ) -> NDArray[np.uint8]:
        """`render` of N scenes, one after the other in the one world: ``theta`` (N, 3),
        ``position`` (N, 3), ``rotation`` (N, 3, 3) -> (N, 3, height, width)."""
        thetas, positions = np.asarray(theta, float), np.asarray(position, float)
        rotations = np.asarray(rotation, float)
        width, height = self.size
        images = np.empty((thetas.shape[0], 3, height, width), dtype=np.uint8)
        for i in range(thetas.shape[0]):
            self.render(thetas[i], positions[i], rotations[i], out=images[i])
        return images

    def full_density(
        self, theta: ArrayLike, position: ArrayLike, rotation: ArrayLike
    ) -> NDArray[np.uint8]:
        """The reference: the crop rendered at full pixel density, RGB, ``(s height, s width,
        3)`` (row, column, channel, as `
        render_frame` gives it); `render`'s pixel ``[:, i, j]`` is its pixel
        ``[s i + s // 2, s j + s // 2]`` (module docstring). Far costlier than `render`: it shades
        every pixel of the crop."""
        world = self._open_world()
        world.set_joint_positions(np.asarray(theta, dtype=float).tolist())
        world.set_target_pose(position, rotation)
        return render_frame(world.client, self.model, self.window, self.lighting)

    def _open_world(self) -> World:
        if self._world is None:
            raise RuntimeError("the WorkspaceImager is closed")
        return self._world

    def close(self) -> None:
        """Release the pybullet world; safe twice."""
        if self._world is not None:
            self._world.close()
            self._world = None
