"""A target side recorded ahead (every step at once, many episodes together) is the one the
live single env fills step by step: the same draws, the same numbers."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils import seeding

from capture_bench.engine.task import scenario_camera
from capture_bench.sensing import photogrammetry
from capture_bench.sensing.estimator import TargetEstimator
from capture_bench.task.recording import STEP_TRACKS
from capture_bench.task.scenarios import list_scenarios, load_scenario
from capture_bench.task.target_side import TargetSide

FIELDS = (*STEP_TRACKS, "rotation", "images")  # every recorded track
DISCRETE = ("visible", "estimate_valid", "estimator_status", "reachable")


def _sides(name: str, seeds: range) -> list[TargetSide]:
    scenario = load_scenario(name)
    camera, features = scenario_camera(scenario)
    estimator = TargetEstimator(
        camera.model, features, source=scenario.estimator.source, **scenario.estimator_settings()
    )
    return [
        TargetSide.draw(scenario, camera, estimator, features, seeding.np_random(s)[0])
        for s in seeds
    ]


def _step_by_step(name: str, seeds: range) -> list:
    """Each seed drawn and filled before the next is drawn (they share the estimator, which a
    draw resets), as the live single env plays them."""
    out = []
    for seed in seeds:
        (side,) = _sides(name, range(seed, seed + 1))
        out.append(side.through(side.episode.time.size - 1))
    return out


@pytest.mark.parametrize("name", list_scenarios())
def test_recording_many_sides_equals_filling_each_step_by_step(name):
    """Every field of every row, with the cold photogrammetry of the first frames solved as a
    batch and then solved one by one. The true states and frames are bit for bit on any
    machine; the estimates too where OpenBLAS rounds a stack of small solves as it rounds
    each alone (this project's machines; to rounding elsewhere, see solve_pose_batch)."""
    seeds = range(2_000, 2_006)
    photogrammetry.clear_solve_cache()
    expected = _step_by_step(name, seeds)
    photogrammetry.clear_solve_cache()
    recorded = TargetSide.record_many(_sides(name, seeds))
    for want, got in zip(expected, recorded, strict=True):
        for field in FIELDS:
            a, b = getattr(want, field), getattr(got, field)
            if field in DISCRETE or field in ("time", "dt", "position", "velocity", "rotation"):
                np.testing.assert_array_equal(b, a, err_msg=field)
            else:
                np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12, err_msg=field)
    photogrammetry.clear_solve_cache()
    (alone,) = [side.record_all() for side in _sides(name, range(2_000, 2_001))]
    np.testing.assert_array_equal(alone.images, expected[0].images)
    np.testing.assert_array_equal(alone.estimate_position, expected[0].estimate_position)


def test_a_side_already_stepped_is_finished_step_by_step():
    """A live side the env has filled part of keeps its rows and fills the rest in order."""
    (full,) = _step_by_step("noisy", range(7, 8))
    (side,) = _sides("noisy", range(7, 8))
    side.through(5)
    done = side.record_all()
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(done, field), getattr(full, field), err_msg=field)


def test_primed_cold_solves_are_the_solves_of_each_image_alone():
    """cold_solves keeps the batch's solution of each image; solve_pose then returns it,
    equal to a fresh solve of that image alone (to rounding on any machine), and the memo
    grows by the images not yet kept."""
    scenario = load_scenario("paper")
    camera, features = scenario_camera(scenario)
    sides = _sides("paper", range(30, 34))
    for side in sides:
        side._record_truth()
    images = np.stack([side._first_frame() for side in sides])
    f = camera.model.focal_length
    photogrammetry.clear_solve_cache()
    photogrammetry.cold_solves(images, features, f)
    assert photogrammetry.solve_cache_size()[0] == 4
    primed = [photogrammetry.solve_pose(image, features, f) for image in images]
    photogrammetry.cold_solves(images[:2], features, f)
    assert photogrammetry.solve_cache_size()[0] == 4
    photogrammetry.clear_solve_cache()
    for image, kept in zip(images, primed, strict=True):
        fresh = photogrammetry.solve_pose(image, features, f)
        np.testing.assert_allclose(kept.pose, fresh.pose, rtol=1e-9, atol=1e-12)
        assert kept.converged == fresh.converged
