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

**Area sampling** (``image_supersample`` m > 1, `PixelOptions`). Each image pixel is the mean of
an m x m grid of samples at the centres of its m x m sub-pixels: the crop rendered at m times the
image's size through the same window (the frustum shifted by half a render pixel, so TinyRenderer
samples each render pixel's centre), then averaged over m x m blocks and rounded to the nearest
uint8. A box filter over the image pixel's footprint on the sensor, by quadrature: with m = s it
is the mean of the s x s full-density pixels the image pixel covers. m = 1 (the default) is the
point sampling above, unchanged. Cost: one render of m^2 times the pixels.

**The end-effector crop** (``ee_crop`` n > 0, `PixelOptions`): a second image, ``ee_image``,
n x n pixels of ``ee_crop_scale`` c sensor pixels each, from the same camera, the same scene and
the same light, its window ``n c`` sensor pixels square centred on the end-effector X_E's
projection (eq. 2, `capture_bench.sensing.pixels.pixel_of`): the window's top-left edge is
``round(u + 0.5 - n c / 2)`` (and the same in v), so its centre lies within half a sensor pixel
of the projection, moved inside the sensor where it would cross an edge (`ee_window`). With n odd
the centre image pixel is the one X_E projects into. At c = 1 the crop is at full sensor density,
~0.56 mm a pixel at the workspace; its own ``ee_crop_supersample`` m' samples a side per pixel,
averaged as the wide image's (m' = c: the exact mean of the c x c sensor pixels it covers).
The arm knows X_E (the observation's ``state`` holds it), so this crop is what a camera with a
region of interest read out around the gripper would give.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.pixels import pixel_of
from capture_bench.sensing.render_camera import (
    TINY_RENDERER_SAMPLE_OFFSET,
    Lighting,
    Window,
    camera_image_request,
    check_window,
    projection_matrix,
    render_frame,
)
from capture_bench.sim.world import World

IMAGE_SIZE = (84, 84)  # (width, height), pixels: the default image
CROP_CENTRE = (0.56, 0.5)  # the crop's centre, fractions of the sensor's width and height
CROP_SIDE = 0.9625  # the crop's longest side, share of the sensor's shorter side (924 of 960)
IMAGE_MARKER_RADIUS = 0.01  # m: the image's target markers

FloatArray = NDArray[np.float64]

#: The pixel observation's options beyond ``image_size``: name -> (default, lowest, highest).
PIXEL_OPTION_RANGES = {
    "frame_stack": (1, 1, 16),  # the last k images, oldest first, along the channels
    "ee_crop": (0, 0, 256),  # the end-effector crop's side n, pixels (0: no crop)
    "ee_crop_scale": (1, 1, 11),  # c: sensor pixels per end-effector crop pixel, a side
    "image_supersample": (1, 1, 11),  # m: samples per image pixel, a side (1: point sampling)
    "ee_crop_supersample": (1, 1, 11),  # the same for the end-effector crop's pixels
}


@dataclass(frozen=True)
class PixelOptions:
    """What the pixel observation holds besides the wide image of ``image_size`` (module
    docstring); the defaults give the original observation (one point-sampled image).

    Attributes:
        frame_stack: k, the last k images of each key, oldest first, stacked along the channels
            (``3 k`` channels); an episode's first observation repeats its first image k times.
        ee_crop: n, the side of the end-effector crop ``ee_image``, pixels; 0: no crop.
        ee_crop_scale: c, sensor pixels per crop pixel, a side (1: full sensor density).
        image_supersample: m, samples per image pixel, a side, averaged (1: one point sample).
        ee_crop_supersample: the same for the end-effector crop (m = c: the exact mean of the
            full-density pixels each crop pixel covers).
    """

    frame_stack: int = 1
    ee_crop: int = 0
    ee_crop_scale: int = 1
    image_supersample: int = 1
    ee_crop_supersample: int = 1

    @classmethod
    def check(cls, **options: Any) -> PixelOptions:
        """The options, each None meaning its default, or ``ValueError`` naming the first bad
        one and its valid range (`PIXEL_OPTION_RANGES`)."""
        values = {}
        for name, value in options.items():
            if name not in PIXEL_OPTION_RANGES:
                raise ValueError(
                    f"unknown pixel option {name!r}; valid: {', '.join(PIXEL_OPTION_RANGES)}"
                )
            default, low, high = PIXEL_OPTION_RANGES[name]
            value = default if value is None else value
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                value = None
            if value is None or not low <= value <= high:
                raise ValueError(
                    f"{name} must be a whole number from {low} to {high}; got {options[name]!r}"
                )
            values[name] = int(value)
        return cls(**values)

    def changed(self) -> dict[str, int]:
        """The options that differ from their defaults (what a model's card records)."""
        return {k: v for k, v in asdict(self).items() if v != PIXEL_OPTION_RANGES[k][0]}


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


def wide_pixels(model: CameraModel, size: tuple[int, int], uv: ArrayLike) -> FloatArray:
    """Sensor pixels ``[u, v]`` (..., 2) -> where they lie in the wide image of ``size``,
    [column, row] in its pixels, fractional: image pixel j shows sensor column u0 + s j + s // 2
    (`crop_window`'s u0, `crop_scale`'s s; the same in rows), so column (u - u0 - s // 2) / s."""
    u0, _, v0, _ = crop_window(model, size)
    s = crop_scale(model, size)
    return (np.asarray(uv, dtype=float) - [u0 + s // 2, v0 + s // 2]) / s


def sensor_pixels(model: CameraModel, size: tuple[int, int], pixels: ArrayLike) -> FloatArray:
    """Wide-image pixels [column, row] (..., 2) of an image of ``size`` -> the sensor pixels
    ``[u, v]`` they show (the inverse of `wide_pixels`)."""
    u0, _, v0, _ = crop_window(model, size)
    s = crop_scale(model, size)
    return np.asarray(pixels, dtype=float) * s + [u0 + s // 2, v0 + s // 2]


def area_mean(rgba: Any, size: tuple[int, int], m: int) -> NDArray[np.uint8]:
    """A render of ``m`` times ``size`` ``(width, height)`` (pybullet's flat RGBA buffer) as the
    image of ``size``, channel-first RGB: each pixel the mean of its m x m render pixels,
    rounded to the nearest whole number."""
    width, height = size
    rgb = np.reshape(rgba, (height * m, width * m, 4))[..., :3]
    if m == 1:
        return rgb.transpose(2, 0, 1)
    total = np.full((height, width, 3), m * m // 2, dtype=np.uint16)  # 11^2 x 255 fits
    for i in range(m):
        for j in range(m):
            total += rgb[i::m, j::m]
    total //= m * m
    return total.astype(np.uint8).transpose(2, 0, 1)


def supersampled_request(
    model: CameraModel, window: Window, size: tuple[int, int], m: int, template: dict[str, Any]
) -> dict[str, Any]:
    """``getCameraImage``'s arguments (``template``'s light and renderer) that render ``window``
    at ``m`` times ``size``, each render pixel sampled at its centre (the frustum shifted by
    TinyRenderer's half-pixel offset of a render pixel, ``(u1 - u0) / (m width)`` sensor
    pixels)."""
    u0, u1, _, _ = check_window(window, model)
    width, height = size
    offset = TINY_RENDERER_SAMPLE_OFFSET * (u1 - u0) / (m * width)
    return {
        **template,
        "width": m * width,
        "height": m * height,
        "projectionMatrix": projection_matrix(model, window, sample_offset=offset),
    }


def ee_window(model: CameraModel, x_e: ArrayLike, side: int) -> Window:
    """The end-effector crop's window, ``side`` sensor pixels square, centred within half a
    sensor pixel on the projection of X_E (global, m, (3,)): top-left edge
    ``round(u + 0.5 - side / 2)`` (u the projection's column, integer at a pixel's centre; the
    same in v), moved inside the sensor where it would cross an edge."""
    u, v = pixel_of(model.to_camera(np.asarray(x_e, float)[None]), model)[0]
    sensor_w, sensor_h = model.resolution
    u0 = min(max(round(u + 0.5 - side / 2), 0), sensor_w - side)
    v0 = min(max(round(v + 0.5 - side / 2), 0), sensor_h - side)
    return (u0, u0 + side, v0, v0 + side)


class WorkspaceImager:
    """Renders the pixel observation (module docstring) from a pybullet world of its own.

    Args:
        model: the eye-to-hand camera.
        features: the target's feature points (marker centres), target frame, m, (4, 3).
        size: the image's ``(width, height)``, pixels (`check_image_size`).
        lighting: the light; None for ``Lighting()`` (from the lens).
        marker_radius: the target's marker radius, m.
        options: the area sampling and the end-effector crop (`PixelOptions`; its
            ``frame_stack`` is the engine's); None: the defaults.

    Attributes:
        size: ``(width, height)``; scale: s; window: the crop ``(u0, u1, v0, v1)``, sensor pixels;
        options: `PixelOptions`.
    """

    def __init__(
        self,
        model: CameraModel,
        features: ArrayLike,
        size: tuple[int, int] = IMAGE_SIZE,
        lighting: Lighting | None = None,
        marker_radius: float = IMAGE_MARKER_RADIUS,
        options: PixelOptions | None = None,
    ) -> None:
        self.model = model
        self.size = check_image_size(size, model)
        self.scale = crop_scale(model, self.size)
        self.window = crop_window(model, self.size)
        self.lighting = Lighting() if lighting is None else lighting
        self.options = PixelOptions() if options is None else options
        ee_side = self.options.ee_crop * self.options.ee_crop_scale
        if ee_side > min(model.resolution):
            raise ValueError(
                f"ee_crop x ee_crop_scale = {ee_side} sensor pixels is more than the sensor's "
                f"shorter side, {min(model.resolution)}; make the crop or its scale smaller"
            )
        m = self.options.image_supersample
        self._request = camera_image_request(model, self.window, self.lighting, size=self.size)
        if m > 1:
            self._request = supersampled_request(model, self.window, self.size, m, self._request)
        self._template = camera_image_request(model, None, self.lighting)
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
        self._pose(theta, position, rotation)
        return self._shoot(self._request, self.size, out)

    def view_points(self, points: ArrayLike, x_e: ArrayLike) -> dict[str, NDArray[np.float64]]:
        """Where global points (M, 3) lie in each view of a scene whose end-effector is at
        ``x_e`` (global, m, (3,)): ``image`` (M, 2) and, with the crop, ``ee_image`` (M, 2),
        [column, row] in the view's pixels, fractional, pixel (i, j) at (j, i): the point sampled
        for view pixel j is sensor column u0 + s j + s // 2 (module docstring), so a point's
        column is (u - u0 - s // 2) / s for its projection u (eq. 2), and the same in rows (an
        area-sampled pixel's footprint is centred at u0 + s j + (s - 1) / 2: the same for odd s,
        half a sensor pixel earlier for even s)."""
        uv = pixel_of(self.model.to_camera(np.asarray(points, float).reshape(-1, 3)), self.model)
        found = {"image": self._wide_pixels(uv)}
        n, c = self.options.ee_crop, self.options.ee_crop_scale
        if n > 0:
            e0, _, f0, _ = ee_window(self.model, x_e, n * c)
            found["ee_image"] = (uv - [e0 + c // 2, f0 + c // 2]) / c
        return found

    def image_points(self, points: ArrayLike) -> NDArray[np.float64]:
        """Where global points (..., 3) lie in the wide image, [column, row] in its pixels,
        (..., 2) (`view_points`'s ``image``)."""
        p = np.asarray(points, float)
        uv = pixel_of(self.model.to_camera(p.reshape(-1, 3)), self.model)
        return self._wide_pixels(uv).reshape(*p.shape[:-1], 2)

    def _wide_pixels(self, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        return wide_pixels(self.model, self.size, uv)

    def render_ee(
        self,
        theta: ArrayLike,
        position: ArrayLike,
        rotation: ArrayLike,
        x_e: ArrayLike,
        out: NDArray[np.uint8] | None = None,
    ) -> NDArray[np.uint8]:
        """The end-effector crop (module docstring) of the scene `render` draws, centred on
        X_E (global, m, (3,)): uint8 RGB, ``(3, n, n)``, written into ``out`` if given."""
        self._pose(theta, position, rotation)
        return self._shoot_ee(x_e, out)

    def render_batch(
        self, theta: ArrayLike, position: ArrayLike, rotation: ArrayLike
    ) -> NDArray[np.uint8]:
        """`render` of N scenes, one after the other in the one world: ``theta`` (N, 3),
        ``position`` (N, 3), ``rotation`` (N, 3, 3) -> (N, 3, height, width)."""
        return self.render_views(theta, position, rotation)["image"]

    def render_views(
        self,
        theta: ArrayLike,
        position: ArrayLike,
        rotation: ArrayLike,
        x_e: ArrayLike | None = None,
    ) -> dict[str, NDArray[np.uint8]]:
        """N scenes, each posed once and drawn in every view it has: ``image`` (N, 3, height,
        width), and with ``ee_crop`` > 0 ``ee_image`` (N, 3, n, n) centred on ``x_e`` (N, 3)."""
        thetas, positions = np.asarray(theta, float), np.asarray(position, float)
        rotations = np.asarray(rotation, float)
        width, height = self.size
        n = thetas.shape[0]
        views = {"image": np.empty((n, 3, height, width), dtype=np.uint8)}
        side = self.options.ee_crop
        if side:
            if x_e is None:
                raise ValueError("the end-effector crop needs x_e, the end-effector positions")
            ends = np.asarray(x_e, float)
            views["ee_image"] = np.empty((n, 3, side, side), dtype=np.uint8)
        for i in range(n):
            self._pose(thetas[i], positions[i], rotations[i])
            self._shoot(self._request, self.size, views["image"][i])
            if side:
                self._shoot_ee(ends[i], views["ee_image"][i])
        return views

    def _pose(self, theta: ArrayLike, position: ArrayLike, rotation: ArrayLike) -> None:
        world = self._open_world()
        world.set_joint_positions(np.asarray(theta, dtype=float).tolist())
        world.set_target_pose(position, rotation)

    def _shoot(
        self, request: dict[str, Any], size: tuple[int, int], out: NDArray[np.uint8] | None
    ) -> NDArray[np.uint8]:
        """Render ``request`` in the posed world and area-average it down to ``size``."""
        _, _, rgba, _, _ = self._open_world().client.getCameraImage(**request)
        image = area_mean(rgba, size, request["width"] // size[0])
        if out is None:
            return np.ascontiguousarray(image, dtype=np.uint8)
        out[...] = image
        return out

    def _shoot_ee(self, x_e: ArrayLike, out: NDArray[np.uint8] | None) -> NDArray[np.uint8]:
        n, c = self.options.ee_crop, self.options.ee_crop_scale
        window = ee_window(self.model, x_e, n * c)
        m = self.options.ee_crop_supersample
        request = supersampled_request(self.model, window, (n, n), m, self._template)
        return self._shoot(request, (n, n), out)

    def full_density(
        self, theta: ArrayLike, position: ArrayLike, rotation: ArrayLike
    ) -> NDArray[np.uint8]:
        """The reference: the crop rendered at full pixel density, RGB, ``(s height, s width,
        3)`` (row, column, channel, as `
        render_frame` gives it); `render`'s pixel ``[:, i, j]`` is its pixel
        ``[s i + s // 2, s j + s // 2]`` (module docstring). Far costlier than `render`: it shades
        every pixel of the crop."""
        self._pose(theta, position, rotation)
        return render_frame(self._open_world().client, self.model, self.window, self.lighting)

    def _open_world(self) -> World:
        if self._world is None:
            raise RuntimeError("the WorkspaceImager is closed")
        return self._world

    def close(self) -> None:
        """Release the pybullet world; safe twice."""
        if self._world is not None:
            self._world.close()
            self._world = None
