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
    for reader in ("softmax", "centroid", "marker", "hand", "oracle"):
        args = ["--train-steps", "48", "--validation-steps", "32", "--epochs", "1",
                "--episodes", "2", "--window", "2", "--reader", reader, "--oracle-noise", "0.1",
                "--out", str(out)]  # fmt: skip
        if reader == "centroid":  # then the head alone, reading the last two steps' features
            args += ["--head-epochs", "1", "--head-stack", "2"]
        if reader == "oracle":  # markers 2-4's features, and a DAgger round
            args += ["--features", "markers", "--leave-out", "1", "--dagger", "1",
                     "--dagger-steps", "32"]  # fmt: skip
        assert probe.main(args) == 0
        report = __import__("json").loads(out.read_text())
        assert report["rows"] == 32 and report["episodes"] == 2
        assert report["command"].startswith("python scripts/pixel_keypoint_probe.py --train-steps")
        assert report["window"] == {"image": 2} and report["reader"] == reader
        assert 0 <= report["captured"] <= 2
        read = 4 if reader in ("marker", "hand") else 5  # the markers' readers read no X_E
        assert len(report["image_keypoint_median_px"]) == read
        assert all(np.isfinite(report["relative_median_mm"]))
        assert report["head_stack"] == (2 if reader == "centroid" else 1)
        assert report["features"] == ("markers" if reader == "oracle" else "all")
        rounds = report["dagger_rounds"]
        assert len(rounds) == (1 if reader == "oracle" else 0)
        if rounds:  # played before the round, on the first collection's rows
            assert rounds[0]["rows"] == 48 and 0 <= rounds[0]["captured"] <= 2
        if reader == "oracle":  # fed the true points plus the noise asked for
            assert report["oracle_noise_px"] == 0.1 and report["leave_out"] == 1
            assert all(0.05 < e < 0.2 for e in report["image_keypoint_median_px"])


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


def test_the_centroid_reader_reads_every_view_and_gives_detection_logits(load_script):
    import torch

    probe = load_script("pixel_keypoint_probe")
    sizes = {"image": 84, "ee_image": 75}
    net = probe.ProbeNet(sizes, {"image": 3, "ee_image": 11}, "centroid")
    views = {k: torch.zeros((2, 3, s, s), dtype=torch.uint8) for k, s in sizes.items()}
    x, keypoints, logits = net.features(views, torch.zeros((2, 7)))
    assert x.shape == (2, 2 * net.views["image"].dim + 7)
    for k, half in (("image", 3), ("ee_image", 11)):
        assert logits[k].shape == (2, probe.KEYPOINTS, sizes[k], sizes[k])
        # a blank image: the logits' first pixel is their largest, the weights are uniform, so
        # each keypoint is the centre of the window moved inside the view from that corner
        np.testing.assert_allclose(keypoints[k][0].detach().numpy(), half, atol=1e-4)


@pytest.mark.parametrize("reader", ["oracle", "softmax", "centroid", "marker"])
def test_the_markers_features_read_the_first_keypoints_alone(reader, load_script):
    """``read`` = 4: the features are the four markers' (X_E and the other maps not read):
    moving X_E's point (the oracle) or the maps beyond the fourth changes none of them."""
    import torch

    probe = load_script("pixel_keypoint_probe")
    torch.manual_seed(0)
    net = probe.ProbeNet({"image": 84}, 3, reader, points=5, read=4)
    assert net.views["image"].dim == probe.feature_width(4)
    if reader == "oracle":
        points = torch.rand((2, 5, 2)) * 83
        moved = points.clone()
        moved[:, 4] += 7.0
        views = [{"image": points}, {"image": moved}]
    else:
        views = [{"image": torch.randint(0, 256, (2, 3, 84, 84), dtype=torch.uint8)}] * 2
    x, _, _ = net.features(views[0], torch.zeros((2, 7)))
    assert x.shape == (2, probe.feature_width(4) + 7)
    if reader == "marker":  # one map per marker, nothing beyond them
        assert net.views["image"].marker.detect[2].out_channels == 4
    elif reader != "oracle":  # the maps beyond the markers' carry no weight into the features
        view = net.views["image"]
        last = view.weights[2] if reader == "centroid" else view.maps[2]  # to the maps
        with torch.no_grad():
            last.weight[4:] += 1.0
            last.bias[4:] += 1.0
    moved_x, _, _ = net.features(views[1], torch.zeros((2, 7)))
    torch.testing.assert_close(moved_x, x)


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


def test_fit_head_moves_the_mlp_alone_and_fits_it(load_script):
    import torch

    probe = load_script("pixel_keypoint_probe")
    rng = np.random.default_rng(0)
    n = 256
    state = rng.standard_normal((n, 7)).astype(np.float32)
    action = np.tanh(state[:, :3] - 0.5 * state[:, 3:6]).astype(np.float32)
    views = {"image": rng.integers(0, 256, (n, 3, 24, 24), dtype=np.uint8)}
    rows = probe.Rows(views, {"image": rng.uniform(0, 23, (n, 5, 2)).astype(np.float32)},
                      state, action, action.copy())  # fmt: skip
    net = probe.ProbeNet({"image": 24}, 0, "centroid")
    probe.fit(net, rows, 1, 2e-3, True, 0)
    reader = [p.detach().clone() for p in net.views.parameters()]
    trunk = [p.detach().clone() for p in net.trunk.parameters()]

    def error():
        with torch.no_grad():
            a, _, _ = net(*probe._batch(rows, np.arange(n)))
        return float(((a.numpy() - action) ** 2).mean())

    first = error()
    probe.fit_head(net, rows, 30, 2e-3, 0)
    assert error() < 0.5 * first
    assert all(torch.equal(a, b) for a, b in zip(reader, net.views.parameters(), strict=True))
    assert not any(torch.equal(a, b) for a, b in zip(trunk, net.trunk.parameters(), strict=True))


def test_last_steps_hold_the_last_steps_in_order_and_restart_with_an_episode(load_script):
    from capture_bench.engine.engine import FrameStack

    probe = load_script("pixel_keypoint_probe")
    history = FrameStack(2, 3)

    def step(value):
        return {"image": np.full((2, 5, 2), value, dtype=np.float32)}

    first = probe.last_steps(history, step(1.0), 0)
    assert first["image"].shape == (2, 3, 5, 2) and np.all(first["image"] == 1.0)  # filled
    assert first["image"].dtype == np.float32
    probe.last_steps(history, step(2.0), 1)
    history.restart(np.array([1]))  # sub-env 1's episode restarts
    third = probe.last_steps(history, step(3.0), 2)
    np.testing.assert_array_equal(third["image"][0, :, 0, 0], [1.0, 2.0, 3.0])  # oldest first
    np.testing.assert_array_equal(third["image"][1, :, 0, 0], [3.0, 3.0, 3.0])
    fourth = probe.last_steps(history, step(4.0), 3)
    np.testing.assert_array_equal(fourth["image"][0, :, 0, 0], [2.0, 3.0, 4.0])
    np.testing.assert_array_equal(third["image"][0, :, 0, 0], [1.0, 2.0, 3.0])  # a copy


def test_the_probe_collects_the_points_of_the_last_steps(load_script):
    probe = load_script("pixel_keypoint_probe")
    rows = probe.collect("paper", {"image_supersample": 3}, 64, list(range(16 * 64)), stack=3)
    h, p = rows.history["image"], rows.points["image"]
    assert h.shape == (64, 3, 5, 2)
    np.testing.assert_array_equal(h[:, -1], p)  # the newest is the row's own
    np.testing.assert_array_equal(h[:16, 0], p[:16])  # the episodes' first rows: filled
    np.testing.assert_array_equal(h[16:, 1], p[:48])  # then the same sub-env's step before
    assert rows.first.shape == (64,) and rows.first[:16].all() and not rows.first[16:].any()


def test_the_rows_marked_first_are_the_episodes_first_steps(load_script):
    """With next-step autoreset the row after an episode's last is the next one's first: the
    rows marked first are those where the arm is at its start (every episode starts it there),
    and their last steps are their own."""
    probe = load_script("pixel_keypoint_probe")
    rows = probe.collect("paper", {"image_supersample": 1}, 16 * 40, list(range(16 * 64)), 2)
    at_start = np.all(rows.state[:, :3] == rows.state[0, :3], axis=1)
    assert at_start[16:].any()  # an episode ended and the next started within the rows
    np.testing.assert_array_equal(rows.first, at_start)
    h, p = rows.history["image"], rows.points["image"]
    np.testing.assert_array_equal(h[rows.first, 0], p[rows.first])


def test_a_students_rows_are_its_states_labelled_by_the_teacher(load_script):
    """DAgger's rows: a student that holds the arm still keeps it at its start, and every row is
    labelled with what the teacher would do there (it would move)."""
    import torch

    probe = load_script("pixel_keypoint_probe")
    net = probe.ProbeNet({"image": 84}, 0, "oracle", points=5, read=4)
    with torch.no_grad():
        net.head.weight.zero_()
        net.head.bias.zero_()
    student = probe.Student(net, 0.1, np.random.default_rng(0))
    rows = probe.collect("paper", {"image_supersample": 1}, 64, list(range(16 * 64)), 1, student)
    assert np.all(rows.state[:, :3] == rows.state[0, :3])  # the arm never moved
    assert np.all(np.abs(rows.action).max(axis=1) > 0.1)  # the teacher would have moved it


def test_stacked_gives_each_row_its_sub_envs_steps_before(load_script):
    import torch

    probe = load_script("pixel_keypoint_probe")
    n = probe.NUM_ENVS
    x = torch.arange(4 * n, dtype=torch.float32)[:, None]  # 4 steps of n sub-envs
    first = np.zeros(4 * n, dtype=bool)
    first[:n] = True  # every episode starts at step 0
    first[2 * n + 1] = True  # sub-env 1 starts a new episode at step 2
    got = probe.stacked(x, first, 3)[..., 0].numpy()
    assert got.shape == (4 * n, 3)
    np.testing.assert_array_equal(got[0], [0, 0, 0])
    np.testing.assert_array_equal(got[3 * n], [n, 2 * n, 3 * n])  # oldest first
    np.testing.assert_array_equal(got[2 * n + 1], [2 * n + 1] * 3)  # its episode's first step
    np.testing.assert_array_equal(got[3 * n + 1], [2 * n + 1, 2 * n + 1, 3 * n + 1])


def test_the_hand_reader_finds_rendered_markers_to_a_tenth_of_a_pixel(load_script):
    """The probe's hand reader, no parameters, on the wide frames the pixel env renders
    (``image_supersample=3``): at the median each marker is read to < 0.1 px of where
    `view_points` puts it, and no window is misplaced by more than a pixel where the marker
    shows (its weight at least half the median's)."""
    import torch

    probe = load_script("pixel_keypoint_probe")
    rows = probe.collect("paper", {"image_supersample": 3}, 64, list(range(16 * 64)))
    with torch.no_grad():
        pixels, mass, logits = probe.HandReader()(torch.as_tensor(rows.views["image"]) / 255.0)
    assert logits is None
    error = np.linalg.norm(pixels.numpy() - rows.points["image"][:, :4], axis=-1)
    assert np.all(np.median(error, axis=0) < 0.1), np.median(error, axis=0)
    shows = mass.numpy() >= 0.5 * np.median(mass.numpy(), axis=0)
    assert shows.mean() > 0.8
    assert np.all(error[shows] < 1.0), error[shows].max()


def test_the_oracle_left_without_a_marker_reads_the_others_alone(load_script, capsys):
    """``--leave-out 1``: the oracle's features read markers 2-4; moving marker 1's point (or
    X_E's) changes none of them, moving marker 2's does; with another reader it is refused in
    one line."""
    import torch

    probe = load_script("pixel_keypoint_probe")
    net = probe.ProbeNet({"image": 84}, 0, "oracle", points=5, read=4, leave_out=0)
    assert net.views["image"].dim == probe.feature_width(3)
    points = torch.rand((2, 5, 2)) * 83
    x, _, _ = net.features({"image": points}, torch.zeros((2, 7)))
    for moved_point, changes in ((0, False), (4, False), (1, True)):
        moved = points.clone()
        moved[:, moved_point] += 7.0
        moved_x, _, _ = net.features({"image": moved}, torch.zeros((2, 7)))
        assert (not torch.allclose(moved_x, x)) == changes, moved_point
    assert probe.main(["--reader", "hand", "--leave-out", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pixel_keypoint_probe: --leave-out") and "\n" not in err


def test_a_marker_shows_where_its_hand_weight_is_near_the_frames_largest(load_script):
    """`shown_share`: on most first frames every marker shows (the block hides some); a grey
    square over a marker of a frame where all four show hides that marker alone."""
    probe = load_script("pixel_keypoint_probe")
    rows = probe.collect("paper", {"image_supersample": 3}, 16, list(range(16 * 64)))
    views = rows.views["image"]
    assert np.all(probe.shown_share(views) > 0.75)
    whole = next(i for i in range(len(views)) if np.all(probe.shown_share(views[i : i + 1]) == 1))
    frame = views[whole : whole + 1].copy()
    x, y = np.round(rows.points["image"][whole, 2]).astype(int)
    frame[:, :, y - 3 : y + 4, x - 3 : x + 4] = 128  # marker 3 behind something grey
    np.testing.assert_array_equal(probe.shown_share(frame), [1, 1, 0, 1])
    np.testing.assert_array_equal(probe.shown_share(np.full_like(frame, 255)), [0, 0, 0, 0])
