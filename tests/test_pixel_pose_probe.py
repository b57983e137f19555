"""scripts/pixel_pose_probe.py: the markers through the estimator's photogrammetry give the
capture point where the target is, from three markers too once warm-started, and the probe runs
end to end and refuses bad input in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

OPTIONS = {"image_supersample": 3}


@pytest.fixture(scope="module")
def rows_and_probe(load_script):
    probe = load_script("pixel_pose_probe")
    rows = probe.keypoint_probe.collect("paper", OPTIONS, 32, list(range(16 * 64)))
    return probe, rows


def test_the_markers_pose_puts_the_capture_point_where_the_target_is(rows_and_probe):
    """Exact points of all four markers: the capture point less X_E is the relative vector
    (eq. 13's prediction, a step's drift from it) to a millimetre; then from markers 2-4 alone,
    warm-started from that pose, the same to a tenth of a millimetre; a step with two markers
    keeps the last pose and says it was not solved."""
    probe, rows = rows_and_probe
    reading = probe.pose_reading("paper")
    step = np.arange(16)
    points = rows.points["image"][step, :4].astype(float)
    x_e = rows.state[step, 3:6].astype(float)
    all_four = reading.pose(points, np.ones((16, 4), dtype=bool), x_e)
    assert np.all(all_four[:, 3] == 1) and np.all(all_four[:, 4] == 1)
    np.testing.assert_allclose(all_four[:, :3] / probe.DECIMETRES, rows.relative[step], atol=1e-3)
    three = np.array([[False, True, True, True]] * 16)
    from_three = reading.pose(points, three, x_e)
    np.testing.assert_allclose(from_three[:, :3], all_four[:, :3], atol=1e-3)  # 0.1 mm
    np.testing.assert_allclose(from_three[:, 4], 0.75)
    two = np.array([[False, False, True, True]] * 16)
    kept = reading.pose(points + 3.0, two, x_e)  # the points moved: not read, the last pose stands
    assert np.all(kept[:, 3] == 0)
    np.testing.assert_allclose(kept[:, :3], from_three[:, :3])
    reading.restart(np.arange(8))
    restarted = reading.pose(points, two, x_e)
    assert np.all(restarted[:8, :3] == 0) and np.all(restarted[8:, :3] == kept[8:, :3])


def test_pose_rows_read_the_hand_markers_of_every_row(rows_and_probe):
    probe, rows = rows_and_probe
    reading = probe.pose_reading("paper")
    features = probe.pose_rows(rows, reading, oracle=False)
    assert features.shape == (32, probe.WIDTH)
    solved = features[:, 3] == 1
    assert solved.mean() > 0.8  # the arm at its start hides few markers
    error = np.abs(features[solved, :3] / probe.DECIMETRES - rows.relative[solved])
    assert np.median(error) < 0.005  # metres, hand-read markers


def test_the_pose_probe_runs_and_refuses_bad_input_in_one_line(tmp_path, capsys, load_script):
    probe = load_script("pixel_pose_probe")
    out = tmp_path / "pose.json"
    args = ["--train-steps", "48", "--validation-steps", "32", "--epochs", "1", "--episodes", "2",
            "--stack", "2", "--reader", "oracle", "--out", str(out)]  # fmt: skip
    assert probe.main(args) == 0
    report = json.loads(out.read_text())
    assert report["command"].startswith("python scripts/pixel_pose_probe.py --train-steps 48")
    assert report["rows"] == 32 and report["episodes"] == 2 and 0 <= report["captured"] <= 2
    assert report["reader"] == "oracle" and report["stack"] == 2
    assert all(np.isfinite(report["relative_median_mm"]))
    capsys.readouterr()
    assert probe.main(["--stack", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pixel_pose_probe:") and "\n" not in err
    assert probe.main(["--scenario", "nowhere", "--train-steps", "16"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pixel_pose_probe:") and "\n" not in err


def test_a_cold_reading_carries_no_pose(rows_and_probe):
    """``--cold``: each step's pose from the multi-start alone; four exact markers still give
    the relative vector, and a step it cannot solve has no pose (zeros), not the last one."""
    probe, rows = rows_and_probe
    reading = probe.pose_reading("paper", warm=False)
    step = np.arange(16)
    points = rows.points["image"][step, :4].astype(float)
    x_e = rows.state[step, 3:6].astype(float)
    four = reading.pose(points, np.ones((16, 4), dtype=bool), x_e)
    np.testing.assert_allclose(four[:, :3] / probe.DECIMETRES, rows.relative[step], atol=1e-3)
    two = reading.pose(points, np.array([[False, False, True, True]] * 16), x_e)
    assert np.all(two[:, :4] == 0)
