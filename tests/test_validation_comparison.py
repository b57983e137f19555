"""scripts/validation_comparison.py: arms of policies on the same validation seeds, each arm's mean
over its training seeds with Student's t interval, and the paired difference from the first arm;
bad input in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

MODEL = "models/dagger-dls-paper/seeds/0"


def test_the_interval_is_students_t_over_the_seeds(load_script):
    script = load_script("validation_comparison")
    mean, low, high = script.interval([0.5, 0.7, 0.9])
    assert mean == pytest.approx(0.7)
    assert high - mean == pytest.approx(4.302653 * 0.2 / np.sqrt(3), rel=1e-6)  # t(0.975, 2)
    assert script.interval([0.4]) == [0.4, 0.4, 0.4]


def test_the_paired_difference_resamples_the_episode_seeds(load_script):
    script = load_script("validation_comparison")
    ours = np.array([[1, 1, 0, 1], [1, 0, 0, 1]], dtype=float)
    theirs = np.array([[1, 0, 0, 0]], dtype=float)
    mean, low, high = script.paired_difference(ours, theirs)
    assert mean == pytest.approx((0 + 0.5 + 0 + 1) / 4)
    assert 0 <= low <= mean <= high <= 1
    assert script.paired_difference(theirs, theirs) == [0.0, 0.0, 0.0]


def test_arms_play_the_same_seeds_and_the_report_says_so(load_script, tmp_path):
    script = load_script("validation_comparison")
    out = tmp_path / "v.json"
    argv = ["--episodes", "2", "--arm", "a", MODEL, "--arm", "b", MODEL, "--out", str(out)]
    assert script.main(argv) == 0
    report = json.loads(out.read_text())
    assert report["command"].startswith("python scripts/validation_comparison.py --episodes 2")
    assert len(report["seeds"]) == 2
    a, b = report["arms"]["a"], report["arms"]["b"]
    assert a["policies"][0]["captured"] == b["policies"][0]["captured"]
    assert b["capture_rate_less_a"] == [0.0, 0.0, 0.0]


@pytest.mark.parametrize(
    "argv",
    [
        ["--arm", "a"],
        ["--arm", "a", "nowhere"],
        ["--episodes", "0", "--arm", "a", MODEL],
        ["--arm", "a", MODEL, "--arm", "a", MODEL],
    ],
)
def test_bad_input_is_one_line(load_script, capsys, argv):
    script = load_script("validation_comparison")
    assert script.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("validation_comparison:") and "\n" not in err, err
