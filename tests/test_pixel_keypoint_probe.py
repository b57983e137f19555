"""The privileged points a pixel network can be supervised on, checked against the images they
describe, and scripts/pixel_keypoint_probe.py end to end on a few rows."""

from __future__ import annotations

import numpy as np
import pytest

from capture_bench.engine.task import CaptureTask
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.sensing.detector import detect_markers
from capture_bench.sim.kinematics import HOME, forward_kinematics
from capture_bench.task.scenarios import load_scenario

CROP = {"image_supersample": 3, "ee_crop": 75, "ee_crop_scale": 3}


def test_true_features_are_the_targets_markers_where_the_target_is():
    env = CaptureVectorEnv(3, "paper", observation_source="pixels")
    try:
        env.reset(seed=5)
        for _ in range(4):
            env.step(np.zeros((3, 3), dtype=np.float32))
        points, truth = env.true_features(), env.true_observation()
        features = env._live_engine().task.features
    finally:
        env.close()
    assert points.shape == (3, len(features), 3)
    assert np.all(features[0] == 0.0)  # paper's capture point is its first marker
    np.testing.assert_allclose(points[:, 0], truth[:, 0:3], atol=1e-6)  # float32 observation
    spacing = np.linalg.norm(features[:, None] - features[None], axis=-1)
    for row in points:  # a rigid motion of the features
        np.testing.assert_allclose(np.linalg.norm(row[:, None] - row[None], axis=-1), spacing,
                                   atol=1e-12)  # fmt: skip


def test_view_points_are_where_the_rendered_markers_and_the_end_effector_are():
    """Independent of the projection: the detector's centroids of the rendered markers, in the
    area-sampled wide image and in the end-effector crop, against `view_points`."""
    task = CaptureTask(load_scenario("paper"), observation_source="pixels", **CROP)
    imager = task.imager()
    try:
        theta = np.asarray(HOME, dtype=float)
        x_e = forward_kinematics(theta)
        position, rotation = x_e + [0.0, 0.0, 0.03], np.eye(3)
        views = imager.render_views(theta[None], position[None], rotation[None], x_e[None])
        points = imager.view_points(np.vstack([position + task.features, x_e]), x_e)
    finally:
        imager.close()
    for key, tolerance in (("image", 0.3), ("ee_image", 0.15)):
        image = np.ascontiguousarray(views[key][0].transpose(1, 2, 0))
        found = detect_markers(image, None, min_area=1, min_fill=0.0)
        assert found.found.any(), key
        error = np.linalg.norm(found.pixels[found.found] - points[key][:4][found.found], axis=1)
        assert np.all(error < tolerance), (key, error)
    # X_E projects into the crop's centre pixel (n odd), within half a sensor pixel
    assert np.all(np.abs(points["ee_image"][4] - 37) <= 0.5 / 3 + 1e-9)


def test_the_probe_collects_fits_measures_and_plays(tmp_path, load_script):
    probe = load_script("pixel_keypoint_probe")
    rows = probe.collect("paper", CROP, 48, list(range(16 * 64)))
    assert rows.views["image"].shape == (48, 3, 84, 84)
    assert rows.views["ee_image"].shape == (48, 3, 75, 75)
    assert rows.points["ee_image"].shape == (48, 5, 2)
    np.testing.assert_allclose(rows.points["ee_image"][:, 4], 37, atol=0.5 / 3 + 1e-6)
    assert np.all(np.abs(rows.action) <= 1.0)
    # the first sub-env's first row is its episode's start: the relative vector of the reset
    env = CaptureVectorEnv(1, "paper")
    try:
        env.reset(seed=0)
        start = env.true_observation()[0, 12:15] * 0.5
    finally:
        env.close()
    np.testing.assert_allclose(rows.relative[0], start, atol=1e-6)

    out = tmp_path / "probe.json"
    args = ["--train-steps", "48", "--validation-steps", "32", "--epochs", "1", "--episodes", "2",
            "--window", "2", "--out", str(out)]  # fmt: skip
    assert probe.main(args) == 0
    report = __import__("json").loads(out.read_text())
    assert report["rows"] == 32 and report["episodes"] == 2 and report["window"] == 2
    assert 0 <= report["captured"] <= 2
    assert len(report["image_keypoint_median_px"]) == 5  # four markers and X_E
    assert all(np.isfinite(report["relative_median_mm"]))


def test_the_probe_refuses_an_unknown_scenario_in_one_line(capsys, load_script):
    probe = load_script("pixel_keypoint_probe")
    assert probe.main(["--scenario", "nowhere", "--train-steps", "16"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pixel_keypoint_probe:") and "\n" not in err


@pytest.mark.parametrize(("crop", "window"), [(0, 0), (75, 3)])
def test_the_probe_network_reads_every_view(crop, window, load_script):
    probe = load_script("pixel_keypoint_probe")
    sizes = {"image": 84, **({"ee_image": crop} if crop else {})}
    net = probe.ProbeNet(sizes, window)
    import torch

    views = {k: torch.zeros((2, 3, s, s), dtype=torch.uint8) for k, s in sizes.items()}
    action, relative, keypoints = net(views, torch.zeros((2, 7)))
    assert action.shape == (2, 3) and relative.shape == (2, 3)
    assert set(keypoints) == set(sizes)
    for k, found in keypoints.items():
        assert len(found) == (2 if window else 1)  # the whole view's, then the local ones
        # a blank image: every map uniform, the whole view's keypoints at its centre
        np.testing.assert_allclose(found[0].detach().numpy(), (sizes[k] - 1) / 2, atol=1e-3)


def test_the_local_soft_argmax_finds_a_peaks_sub_pixel_centre_the_whole_view_misses(load_script):
    import torch

    probe = load_script("pixel_keypoint_probe")
    ys, xs = torch.meshgrid(torch.arange(30.0), torch.arange(40.0), indexing="ij")
    centre = torch.tensor([20.3, 11.7])
    maps = 5.0 * torch.exp(-((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2) / 2.0)
    found = probe.local_soft_argmax(maps[None, None], torch.tensor(1.0), 3)[0, 0]
    assert torch.linalg.vector_norm(found - centre) < 0.12
    weights = torch.softmax(maps.flatten(), 0)  # the whole view: the background pulls it away
    whole = torch.stack(((weights * xs.flatten()).sum(), (weights * ys.flatten()).sum()))
    assert torch.linalg.vector_norm(whole - centre) > 1.0
