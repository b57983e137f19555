"""Tests of the rendered camera's core: pybullet matrices from the intrinsics, the pixel mapping of
eq. 2, the exact image of a sphere, marker rendering and the colour-blob detector.

Rendering is TinyRenderer on the CPU: a full 1280 x 960 frame costs ~0.1 s, a window around one
marker ~1 ms, so these tests render windows and share the one full frame they need.
"""

from __future__ import annotations

import math
from xml.etree import ElementTree

import cv2
import numpy as np
import pytest
from scipy.spatial import ConvexHull

from capture_bench._quiet import quiet_c_output
from capture_bench.sensing import detector as det
from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.occlusion import hidden_markers
from capture_bench.sensing.pixels import (
    image_plane_to_pixel,
    pixel_of,
    pixel_to_global,
    pixel_to_image_plane,
    principal_point,
    sphere_image,
)
from capture_bench.sensing.render_camera import (
    FAR_PLANE,
    NEAR_PLANE,
    Lighting,
    check_window,
    lens_position,
    projection_matrix,
    render_frame,
    vertical_fov,
    view_matrix,
    window_around,
)
from capture_bench.sim import kinematics
from capture_bench.sim.markers import (
    BLOCK_COLOUR,
    MARKER_COLOURS,
    MARKER_RADIUS,
    block_corners,
    create_marked_target,
)
from capture_bench.sim.rotations import quaternion_xyzw
from capture_bench.sim.target_motion import FEATURE_POINTS, random_rotation, random_unit_vector
from capture_bench.sim.world import ARM_URDF, World
from capture_bench.task.scenarios import CameraConfig

with quiet_c_output():
    import pybullet
    from pybullet_utils.bullet_client import BulletClient

FEATURES = FEATURE_POINTS["non_coplanar"]
RED = det.MARKER_BANDS[:1]  # the single-sphere scenes use marker 0's colour
ARM_CLEARANCE_Y = -0.06  # m: every arm surface has global y >= -0.05 at any pose with theta1 = 0


def default_camera() -> CameraModel:
    """The scenarios' default camera (CameraConfig), 1.2 m in front of the workspace."""
    return CameraConfig().model()


MODEL = default_camera()
TILTED = CameraModel.looking_at(
    (1.1, -0.9, 0.9), (0.3, 0.1, 0.2), focal_length=0.006, resolution=(640, 480)
)


@pytest.fixture
def bullet():
    """A bare client; tests add what they need."""
    with quiet_c_output():
        client = BulletClient(connection_mode=pybullet.DIRECT)
    yield client
    client.disconnect()


@pytest.fixture
def sphere(bullet):
    """``place(pixel, depth, radius, rotation)``: one red sphere (the only one in view) whose
    centre projects (eq. 2) to ``pixel`` at ``depth`` m beyond the lens; returns its camera-frame
    centre, (1, 3)."""
    bodies: dict[float, int] = {}
    parked = (0.0, -50.0, 0.0)  # behind the camera

    def place(pixel, depth, radius=MARKER_RADIUS, rotation=None):
        if radius not in bodies:
            bodies[radius] = create_marked_target(
                bullet, np.zeros((1, 3)), radius, MARKER_COLOURS[:1], block=False
            )
        for body in bodies.values():
            bullet.resetBasePositionAndOrientation(body, parked, (0, 0, 0, 1))
        centre = pixel_to_global(np.atleast_2d(pixel), np.array([depth]), MODEL)[0]
        bullet.resetBasePositionAndOrientation(
            bodies[radius],
            centre.tolist(),
            (0, 0, 0, 1) if rotation is None else quaternion_xyzw(rotation.tolist()),
        )
        return MODEL.to_camera(centre[None])

    return place


def render_and_detect(bullet, window, fill_test=True, **kwargs):
    """Render ``window`` of the default camera and detect the red marker in it."""
    image = render_frame(bullet, MODEL, window)
    model = MODEL if fill_test else None
    return det.detect_markers(image, model, origin=(window[0], window[2]), bands=RED, **kwargs)


# --- matrices and the pixel mapping (pure functions) --------------------------------------------


@pytest.mark.parametrize("model", [MODEL, TILTED])
def test_view_matrix_is_pybullets_look_at_from_the_lens(bullet, model):
    eye = lens_position(model)
    expected = bullet.computeViewMatrix(
        eye.tolist(), (eye + model.rotation[:, 1]).tolist(), model.rotation[:, 2].tolist()
    )
    np.testing.assert_allclose(view_matrix(model), expected, atol=2e-7)


@pytest.mark.parametrize("model", [MODEL, TILTED])
def test_projection_matrix_without_offset_is_pybullets_fov_matrix(bullet, model):
    width, height = model.resolution
    expected = bullet.computeProjectionMatrixFOV(
        math.degrees(vertical_fov(model)), width / height, NEAR_PLANE, FAR_PLANE
    )
    np.testing.assert_allclose(projection_matrix(model, sample_offset=0.0), expected, rtol=2e-6)
    assert vertical_fov(MODEL) == pytest.approx(2 * math.atan(960 * 3.75e-6 / (2 * 0.008)))


@pytest.mark.parametrize("model", [MODEL, TILTED])
@pytest.mark.parametrize("window", [None, (100, 164, 37, 101), (0, 7, 470, 480)])
def test_matrices_put_each_point_where_eq2_does(model, window):
    """Through P V, a point lands on TinyRenderer's raster coordinate (x, y from the bottom); the
    renderer samples window column i at x = i and row j at y = rows - 1 - j, so the pixel centre
    of eq. 2 is ``(u0 + x, v0 + rows - 1 - y)``."""
    rng = np.random.default_rng(0)
    u0, u1, v0, v1 = check_window(window, model)
    pixels = rng.uniform([-0.5, -0.5], np.array(model.resolution) - 0.5, size=(50, 2))
    points = pixel_to_global(pixels, rng.uniform(0.2, 3.0, 50), model)
    transform = np.reshape(projection_matrix(model, window), (4, 4)).T
    transform = transform @ np.reshape(view_matrix(model), (4, 4)).T
    clip = np.column_stack([points, np.ones(50)]) @ transform.T
    ndc = clip[:, :3] / clip[:, 3:]
    x = (ndc[:, 0] + 1.0) / 2.0 * (u1 - u0)
    y = (ndc[:, 1] + 1.0) / 2.0 * (v1 - v0)
    through_matrices = np.column_stack([u0 + x, v0 + (v1 - v0) - 1 - y])
    np.testing.assert_allclose(
        through_matrices, pixel_of(model.to_camera(points), model), atol=1e-8
    )
    np.testing.assert_allclose(through_matrices, pixels, atol=1e-8)
    assert np.all((ndc[:, 2] > -1) & (ndc[:, 2] < 1))  # inside the near and far planes


def test_pixel_mapping_is_upright_and_spans_the_sensor():
    w, h = MODEL.resolution
    np.testing.assert_allclose(principal_point(MODEL), [(w - 1) / 2, (h - 1) / 2])
    # camera +x to the right, camera +z up (the real image on the sensor is inverted)
    right_up = pixel_of(np.array([[0.1, 1.2, 0.1]]), MODEL)[0]
    assert right_up[0] > (w - 1) / 2 and right_up[1] < (h - 1) / 2
    # the sensor's edges |x_m| = w pitch / 2 are the outer edges of the outer pixels
    half = MODEL.half_extent
    corners = np.array([[half[0], half[1]], [-half[0], -half[1]]])
    np.testing.assert_allclose(
        image_plane_to_pixel(corners, MODEL), [[-0.5, h - 0.5], [w - 0.5, -0.5]]
    )
    points = np.random.default_rng(1).normal(size=(10, 2)) * 1e-3
    np.testing.assert_allclose(
        pixel_to_image_plane(image_plane_to_pixel(points, MODEL), MODEL), points
    )


def test_sphere_image_matches_the_projected_surface():
    """The ellipse against a brute force: the convex hull of 40 000 projected surface points."""
    rng = np.random.default_rng(2)
    surface = rng.normal(size=(40_000, 3))
    surface /= np.linalg.norm(surface, axis=1, keepdims=True)
    for centre_px, depth, radius in [((639.5, 479.5), 1.2, 0.01), ((20.0, 900.0), 0.3, 0.05)]:
        centre = MODEL.to_camera(pixel_to_global(np.array([centre_px]), np.array([depth]), MODEL))
        hull = ConvexHull(pixel_of(centre + radius * surface, MODEL))
        xy = hull.points[hull.vertices]
        cross = xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]
        hull_centroid = np.array(
            [(xy[:, 0] + np.roll(xy[:, 0], -1)) @ cross, (xy[:, 1] + np.roll(xy[:, 1], -1)) @ cross]
        ) / (3 * cross.sum())
        image = sphere_image(centre, radius, MODEL)
        assert image.area[0] == pytest.approx(hull.volume, rel=2e-3)
        np.testing.assert_allclose(image.centre[0], hull_centroid, atol=0.02)
        assert image.semi_major[0] == pytest.approx(
            np.max(np.linalg.norm(xy - image.centre[0], axis=1)), rel=2e-3
        )
    # on the axis: a circle about the principal point, radius f R / (pitch sqrt(D^2 - R^2))
    on_axis = sphere_image(np.array([[0.0, 1.0 + MODEL.focal_length, 0.0]]), 0.01, MODEL)
    r = MODEL.focal_length * 0.01 / (MODEL.pixel_pitch * math.sqrt(1.0 - 1e-4))
    np.testing.assert_allclose(on_axis.centre[0], principal_point(MODEL), atol=1e-9)
    assert on_axis.area[0] == pytest.approx(math.pi * r * r)
    behind = sphere_image(np.array([[0.0, MODEL.focal_length + 0.005, 0.0]]), 0.01, MODEL)
    assert np.isnan(behind.area[0]) and np.isnan(behind.centre[0]).all()


def test_windows_are_checked_and_cut_to_the_sensor():
    assert check_window(None, MODEL) == (0, 1280, 0, 960)
    assert window_around((3.2, 955.0), 10, MODEL) == (0, 14, 945, 960)
    for bad in [(0, 0, 0, 10), (5, 4, 0, 10), (0, 1281, 0, 10), (-1, 10, 0, 10)]:
        with pytest.raises(ValueError, match="window"):
            check_window(bad, MODEL)


def test_hidden_markers_from_geometry():
    lens = lens_position(MODEL)
    near = lens + np.array([0.0, 1.0, 0.0])
    behind_near = lens + 1.3 * (near - lens) + np.array([0.004, 0.0, 0.0])
    aside = lens + np.array([0.2, 1.0, 0.1])
    points = np.array([near, behind_near, aside])
    np.testing.assert_array_equal(hidden_markers(MODEL, points, 0.01), [False, True, False])
    box = np.array([[x, y, z] for x in (0.15, 0.25) for y in (-0.3, -0.28) for z in (0.05, 0.15)])
    box += lens * [1, 0, 1]  # in front of 'aside', between it and the lens
    np.testing.assert_array_equal(hidden_markers(MODEL, points, 0.01, [box]), [False, True, True])
    np.testing.assert_array_equal(
        hidden_markers(MODEL, points, 0.01, [box + [0, 1.0, 0]]), [False, True, False]
    )  # the same box behind every marker


# --- the detector on drawn images ----------------------------------------------------------------


def drawn(discs, size=(120, 160), background=(200, 200, 200)):
    """An RGB image with filled discs ``(centre (u, v), radius px, rgb 0-255, shade)``; the
    shade (0-1) scales the colour's right half, as diffuse light would."""
    image = np.full((*size, 3), background, dtype=np.uint8)
    for centre, radius, rgb, shade in discs:
        mask = np.zeros(size, dtype=np.uint8)
        cv2.circle(mask, centre, radius, 255, -1)
        shaded = np.array(rgb, dtype=float)[None, None] * np.where(
            np.arange(size[1])[None, :, None] > centre[0], shade, 1.0
        )
        image[mask > 0] = shaded.astype(np.uint8).repeat(size[0], 0)[mask > 0]
    return image


def rgb255(colour):
    return tuple(int(round(255 * c)) for c in colour[:3])


def test_detector_centroids_are_the_blob_moments_and_missing_is_nan():
    discs = [
        ((30, 40), 9, rgb255(MARKER_COLOURS[0]), 0.6),
        ((100, 70), 12, rgb255(MARKER_COLOURS[2]), 0.7),
    ]
    image = drawn(discs)
    found = det.detect_markers(image, origin=(500, 300))
    for index, (centre, radius, _, _) in zip((0, 2), discs):
        mask = np.zeros(image.shape[:2], dtype=np.uint8)
        cv2.circle(mask, centre, radius, 255, -1)
        rows, cols = np.nonzero(mask)
        np.testing.assert_allclose(found.pixels[index], [cols.mean() + 500, rows.mean() + 300])
        assert found.areas[index] == rows.size  # the shaded half counts too
    np.testing.assert_array_equal(found.status, [det.FOUND, det.NO_BLOB, det.FOUND, det.NO_BLOB])
    assert np.isnan(found.pixels[[1, 3]]).all() and found.found.tolist() == [
        True,
        False,
        True,
        False,
    ]


def test_detector_ignores_every_other_colour_in_the_world():
    """The URDF's materials, the target block, the floor and the background, lit from 0.2 to
    1.0 of their colour: no pixel falls in any marker's band."""
    urdf = ElementTree.parse(ARM_URDF).getroot()
    others = [tuple(map(float, c.get("rgba").split()[:3])) for c in urdf.iter("color")]
    others += [BLOCK_COLOUR[:3], (0.78, 0.8, 0.76), (1.0, 1.0, 1.0)]  # world.py's floor; sky
    assert len(others) == 8
    shades = np.linspace(0.2, 1.0, 50)
    image = np.array([[[255 * k * c for c in colour] for k in shades] for colour in others])
    hsv = cv2.cvtColor(np.round(image).astype(np.uint8), cv2.COLOR_RGB2HSV)
    for band in det.MARKER_BANDS:
        assert not det.colour_mask(hsv, band).any()
    markers = np.array(
        [[[255 * k * c for c in colour[:3]] for k in shades] for colour in MARKER_COLOURS]
    )
    hsv = cv2.cvtColor(np.round(markers).astype(np.uint8), cv2.COLOR_RGB2HSV)
    for index, band in enumerate(det.MARKER_BANDS):  # each marker in its own band only
        inside = [det.colour_mask(hsv[i : i + 1], band).all() for i in range(len(MARKER_COLOURS))]
        assert inside == [i == index for i in range(len(MARKER_COLOURS))]


def test_detector_flags_small_border_and_split_blobs():
    red = rgb255(MARKER_COLOURS[0])
    small = np.full((40, 40, 3), 200, np.uint8)
    small[20, 20:23] = red  # 3 pixels
    assert det.detect_markers(small, bands=RED).status[0] == det.TOO_SMALL
    assert det.detect_markers(small, bands=RED, min_area=3).status[0] == det.FOUND
    border = drawn([((3, 60), 8, red, 1.0)])
    result = det.detect_markers(border, bands=RED)
    assert result.status[0] == det.AT_BORDER and np.isnan(result.pixels[0]).all()
    split = drawn([((40, 60), 10, red, 1.0)])
    split[:, 38:42] = 120  # a grey bar across the marker
    assert det.detect_markers(split, bands=RED).status[0] == det.SPLIT


# --- rendering -------------------------------------------------------------------------------------


CORNER_INSET = 30.0  # px: the 18 px marker images stay clear of the sensor's edge


@pytest.mark.parametrize(
    "pixel",
    [
        (639.5, 479.5),
        (CORNER_INSET + 0.3, CORNER_INSET + 0.7),
        (1279 - CORNER_INSET - 0.2, CORNER_INSET + 0.1),
        (CORNER_INSET + 0.9, 959 - CORNER_INSET - 0.4),
        (1279 - CORNER_INSET - 0.6, 959 - CORNER_INSET - 0.5),
    ],
)
def test_rendered_sphere_lands_where_eq2_puts_it(sphere, bullet, pixel):
    """Within 0.1 px at the centre and the four corners. The centroid of a sphere's image is the
    centre of its ellipse, which lies ~0.04 px further out than eq. 2's projection of the sphere's
    centre at these corners (``sphere_image``); both are within 0.1 px."""
    centre = sphere(pixel, 1.2)
    image = sphere_image(centre, MARKER_RADIUS, MODEL)
    found = render_and_detect(bullet, window_around(pixel, 26, MODEL))
    assert found.status[0] == det.FOUND
    assert np.linalg.norm(found.pixels[0] - image.centre[0]) < 0.1
    assert np.linalg.norm(found.pixels[0] - np.array(pixel)) < 0.1
    assert 0.9 < found.areas[0] / image.area[0] < 1.0  # the sphere mesh lies inside the sphere


def test_rendered_spheres_across_the_sensor_match_their_ellipses(sphere, bullet):
    rng = np.random.default_rng(3)
    errors = []
    for _ in range(12):
        pixel = rng.uniform([30, 30], [1249, 929])
        centre = sphere(pixel, rng.uniform(0.8, 1.6), rotation=random_rotation(rng))
        found = render_and_detect(bullet, window_around(pixel, 36, MODEL))
        errors.append(
            np.linalg.norm(found.pixels[0] - sphere_image(centre, MARKER_RADIUS, MODEL).centre[0])
        )
    assert max(errors) < 0.1


def test_marker_outside_the_image_is_missing_not_clipped(sphere, bullet):
    for u, expected in [(12.0, det.AT_BORDER), (-5.0, det.AT_BORDER), (-40.0, det.NO_BLOB)]:
        sphere((u, 300.0), 1.2)
        found = render_and_detect(bullet, (0, 64, 268, 332))
        assert found.status[0] == expected, u
        assert np.isnan(found.pixels[0]).all()


def test_marker_below_the_minimum_area_is_missing(sphere, bullet):
    sphere((400.3, 300.6), 1.2, radius=0.0005)  # an image 0.9 px in radius
    found = render_and_detect(bullet, (380, 420, 280, 320))
    assert 0 < found.areas[0] < det.MIN_AREA_PX and found.status[0] == det.TOO_SMALL
    assert np.isnan(found.pixels[0]).all()
    sphere((400.3, 300.6), 1.2)  # 1000 px, but a minimum above that
    found = render_and_detect(bullet, (370, 430, 270, 330), min_area=1200)
    assert found.status[0] == det.TOO_SMALL


def test_half_hidden_marker_is_partial(sphere, bullet):
    centre = sphere((700.0, 500.0), 1.2)
    lens = lens_position(MODEL)
    marker = MODEL.to_global(centre)[0]
    cover = bullet.createVisualShape(
        pybullet.GEOM_BOX, halfExtents=(0.02, 0.002, 0.02), rgbaColor=(0.5, 0.5, 0.5, 1)
    )
    # a plate 0.3 m in front of the marker covering the image's right half
    plate = lens + 0.75 * (marker - lens) + MODEL.rotation @ np.array([0.75 * 0.02, 0.0, 0.0])
    bullet.createMultiBody(0.0, -1, cover, basePosition=plate.tolist())
    window = window_around((700.0, 500.0), 26, MODEL)
    found = render_and_detect(bullet, window)
    assert found.status[0] == det.PARTIAL and np.isnan(found.pixels[0]).all()
    blind = render_and_detect(bullet, window, fill_test=False)  # without the fill test it is biased
    assert blind.status[0] == det.FOUND and abs(blind.pixels[0, 0] - 700.0) > 3.0


def test_side_light_keeps_the_whole_marker(sphere, bullet):
    centre = sphere((500.0, 400.0), 1.2)
    image = render_frame(
        bullet,
        MODEL,
        window_around((500.0, 400.0), 26, MODEL),
        Lighting(source=(3.0, 0.0, 0.5), ambient=0.25, diffuse=0.75, specular=0.0),
    )
    found = det.detect_markers(
        image, MODEL, origin=window_around((500.0, 400.0), 26, MODEL)[::2], bands=RED
    )
    assert found.status[0] == det.FOUND
    assert found.areas[0] / sphere_image(centre, MARKER_RADIUS, MODEL).area[0] > 0.9


# --- the world with the rendered camera's markers ----------------------------------------------


def clear_poses(count, seed=4):
    """Target poses at the default placement (0.25-0.35 m from the home end-effector, markers in
    the central 90 % of the image) where, from geometry alone, no marker can hide another and the
    block and the arm cannot hide any: markers and block in front of the arm (y < -0.06 m)."""
    rng = np.random.default_rng(seed)
    home = kinematics.forward_kinematics(kinematics.HOME)
    poses = []
    while len(poses) < count:
        position = home + rng.uniform(0.25, 0.35) * random_unit_vector(rng)
        rotation = random_rotation(rng)
        points = position + FEATURES @ rotation.T
        block = position + block_corners(FEATURES, MARKER_RADIUS) @ rotation.T
        if (
            MODEL.visible(MODEL.to_camera(points), margin=0.1).all()
            and max(points[:, 1].max() + MARKER_RADIUS, block[:, 1].max()) < ARM_CLEARANCE_Y
            and not hidden_markers(MODEL, points, MARKER_RADIUS, [block]).any()
        ):
            poses.append((position, rotation, points))
    return poses


@pytest.fixture(scope="module")
def world():
    w = World(FEATURES, marker_radius=MARKER_RADIUS)
    yield w
    w.close()


@pytest.fixture(scope="module")
def full_frame(world):
    """One full frame with the arm at home and the target at the first clear pose."""
    position, rotation, points = clear_poses(1)[0]
    world.reset(kinematics.HOME, position, rotation)
    return render_frame(world.client, MODEL), points


def test_world_hook_builds_the_marked_target():
    with World(FEATURES) as plain, World(FEATURES, marker_radius=0.02) as marked:
        shapes = plain.client.getVisualShapeData(plain.target)
        assert len(shapes) == 6 and shapes[2][3][0] == pytest.approx(0.012)  # unchanged default
        shapes = marked.client.getVisualShapeData(marked.target)
        assert len(shapes) == 5  # four markers and the block; their colours: the render tests
        np.testing.assert_allclose([shape[3][0] for shape in shapes[:4]], 0.02)
        np.testing.assert_allclose([shape[5] for shape in shapes[:4]], FEATURES, atol=1e-7)
    with pytest.raises(RuntimeError, match="closed"):
        _ = marked.client


def test_full_frame_finds_every_marker_where_eq2_puts_it(full_frame):
    image, points = full_frame
    found = det.detect_markers(image, MODEL)
    assert found.found.all()
    assert (
        np.linalg.norm(found.pixels - pixel_of(MODEL.to_camera(points), MODEL), axis=1).max() < 0.3
    )


def test_windows_find_every_marker_within_a_third_of_a_pixel(world):
    errors = []
    for position, rotation, points in clear_poses(4, seed=5):
        world.reset(kinematics.HOME, position, rotation)
        expected = pixel_of(MODEL.to_camera(points), MODEL)
        for index, pixel in enumerate(expected):
            window = window_around(pixel, 26, MODEL)
            found = det.detect_markers(
                render_frame(world.client, MODEL, window), MODEL, window[::2]
            )
            assert found.status[index] == det.FOUND
            errors.append(np.linalg.norm(found.pixels[index] - pixel))
    assert max(errors) < 0.3


@pytest.mark.parametrize(
    "window", ["marker", (540, 700, 320, 450), (0, 64, 330, 394), (1216, 1280, 896, 960)]
)
def test_window_render_equals_the_full_frame(world, full_frame, window):
    """Around a marker, over the arm's tip and forearm, at the sensor's left edge (forearm) and
    bottom-right corner (floor edge): the same pixels (TinyRenderer gives identical values; 1
    grey level is allowed)."""
    image, points = full_frame
    position, rotation, _ = clear_poses(1)[0]
    world.reset(kinematics.HOME, position, rotation)
    if window == "marker":
        window = window_around(pixel_of(MODEL.to_camera(points[:1]), MODEL)[0] + 0.3, 31, MODEL)
    part = render_frame(world.client, MODEL, window)
    u0, u1, v0, v1 = window
    whole = image[v0:v1, u0:u1]
    assert np.unique(whole.reshape(-1, 3), axis=0).shape[0] > 1  # not a plain background
    assert np.abs(part.astype(int) - whole.astype(int)).max() <= 1


def test_arm_in_front_of_a_marker_hides_it(world):
    """The end-effector's tip sphere (radius 0.022 m) is put on the line of sight to marker 1,
    0.2 m in front of it: that marker is gone; with the arm at home it is found."""
    position, rotation, points = clear_poses(1, seed=6)[0]
    lens = lens_position(MODEL)
    marker = points[1]
    tip = marker + 0.2 * (lens - marker) / np.linalg.norm(lens - marker)
    solutions = kinematics.inverse_kinematics(tip)
    theta = solutions[kinematics.within_limits(solutions)][0]
    np.testing.assert_allclose(kinematics.forward_kinematics(theta), tip, atol=1e-9)
    pixel = pixel_of(MODEL.to_camera(points[1:2]), MODEL)[0]
    window = window_around(pixel, 26, MODEL)
    world.reset(kinematics.HOME, position, rotation)
    before = det.detect_markers(render_frame(world.client, MODEL, window), MODEL, window[::2])
    world.reset(theta, position, rotation)
    after = det.detect_markers(render_frame(world.client, MODEL, window), MODEL, window[::2])
    assert before.status[1] == det.FOUND
    assert after.status[1] == det.NO_BLOB and np.isnan(after.pixels[1]).all()
