"""scripts/estimate_cost.py: an agent fed the estimate and the true state, side by side."""

from __future__ import annotations

import importlib.util
from pathlib import Path

_PATH = Path(__file__).resolve().parents[1] / "scripts" / "estimate_cost.py"
_SPEC = importlib.util.spec_from_file_location("estimate_cost", _PATH)
assert _SPEC is not None and _SPEC.loader is not None
estimate_cost = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(estimate_cost)


def test_both_feeds_capture_no_faster_than_the_physical_limit(capsys):
    from capture_bench.task.scenarios import load_scenario

    seeds = list(load_scenario("paper").validation_seeds[:4])
    ekf = estimate_cost.measure("paper", seeds, "incremental_ik", "ekf")
    truth = estimate_cost.measure("paper", seeds, "incremental_ik", "truth")
    assert ekf[0] == truth[0] == 1.0  # every one of these paper episodes is captured either way
    assert 1.0 <= ekf[1] < 2.0 and 1.0 <= truth[1] < 2.0  # the limit is a lower bound
    assert estimate_cost.main(["--seeds", "2", "--agents", "hold"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].split()[:2] == ["hold", "0.00"]  # hold never captures: no ratio
