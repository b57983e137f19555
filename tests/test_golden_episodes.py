"""The environments play the golden episodes (``tests/data/golden_episodes.npz``, made by
``scripts/golden_episodes.py``): the same outcomes, failures and steps exactly, and the same
floats (each episode's record, and step by step its observation, reward and distance) to
rounding, rtol 1e-6 and atol 1e-8, on any machine.

On the kind of machine that made the files (`capture_bench.provenance.reproduction_key`
equal to the ``.json``'s) the floats are in fact equal bit for bit, and that is asserted there,
images included (their CRC-32; elsewhere an image's mean to half an intensity level).

Replayed here: every single-env episode, both from a recording (``reuse_target_side=True``, as
made) and live (its documented equal), and the first 16 episodes of every vector case in a
vector env of 16 sub-envs (a row's floats do not depend on which rows share the batch); the
files hold all 64 episodes of a vector case's records for the engine's own tests.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from capture_bench.provenance import reproduction_key

_PATH = Path(__file__).resolve().parent.parent / "scripts" / "golden_episodes.py"
_SPEC = importlib.util.spec_from_file_location("golden_episodes", _PATH)
golden_episodes = importlib.util.module_from_spec(_SPEC)
sys.modules["golden_episodes"] = golden_episodes  # its dataclass looks its module up
_SPEC.loader.exec_module(golden_episodes)

MADE, GOLDEN = golden_episodes.load()
BIT_FOR_BIT = reproduction_key() == reproduction_key(MADE["machine"], MADE["packages"])
CASES = golden_episodes.cases()
VECTOR_SLICE = 16  # the vector cases' episodes replayed here
_FLOATS = ("record", "obs", "distance", "reward")


def differences(expected: dict, got: dict, bit_for_bit: bool) -> list[str]:
    """What differs between a case's stored and played arrays: outcomes, failures and steps
    exactly; the floats bit for bit or to rounding."""
    out = [
        f"{name}: {got[name].tolist()} != {expected[name].tolist()}"
        for name in ("outcome", "failure", "steps")
        if not np.array_equal(got[name], expected[name])
    ]
    if out:
        return out  # the series no longer line up
    for name in _FLOATS + ("image_mean",):
        if name not in expected:
            continue
        want, have = expected[name], got[name]
        if bit_for_bit:
            if not np.array_equal(have, want, equal_nan=True):
                where = np.argwhere(~((have == want) | (np.isnan(have) & np.isnan(want))))
                out.append(f"{name} not bit for bit at {where[:3].tolist()}")
            continue
        tolerance = (
            {"atol": 0.5, "rtol": 0} if name == "image_mean" else {"rtol": 1e-6, "atol": 1e-8}
        )
        try:
            np.testing.assert_allclose(have, want, equal_nan=True, **tolerance)
        except AssertionError as error:
            out.append(f"{name}: {error}")
    if bit_for_bit and "image_crc" in expected:
        if not np.array_equal(got["image_crc"], expected["image_crc"]):
            out.append("image_crc differs")
    return out


def test_the_files_hold_every_case_the_script_plays():
    """The ``.json`` names the script's cases, and the arrays of each line up: a record per
    seed, the series of the first episodes (a row per step and one for the reset)."""
    assert [case["name"] for case in MADE["cases"]] == [case.name for case in CASES]
    assert [tuple(case["seeds"]) for case in MADE["cases"]] == [case.seeds for case in CASES]
    assert MADE["record_columns"] == golden_episodes.record_columns()
    for case in CASES:
        arrays = GOLDEN[case.name]
        episodes = len(case.seeds)
        assert arrays["record"].shape == (episodes, len(MADE["record_columns"])), case.name
        series = min(episodes, golden_episodes.SERIES_EPISODES)
        steps = int(arrays["steps"][:series].sum())
        assert arrays["reward"].shape == (steps,), case.name
        assert arrays["distance"].shape == arrays["obs"].shape[:1] == (steps + series,), case.name


@pytest.mark.parametrize("live", [False, True], ids=["recorded", "live"])
@pytest.mark.parametrize("case", [c for c in CASES if c.kind == "single"], ids=lambda c: c.name)
def test_the_single_env_plays_the_golden_episodes(case, live):
    played = golden_episodes.play(case, live=live)
    assert differences(GOLDEN[case.name], played, BIT_FOR_BIT) == []


@pytest.mark.parametrize("case", [c for c in CASES if c.kind == "vector"], ids=lambda c: c.name)
def test_the_vector_env_plays_the_golden_episodes(case):
    played = golden_episodes.play(case, seeds=case.seeds[:VECTOR_SLICE])
    expected = golden_episodes.first_episodes(GOLDEN[case.name], VECTOR_SLICE)
    assert differences(expected, played, BIT_FOR_BIT) == []


def test_a_last_bit_or_an_outcome_that_moves_is_reported():
    """The comparison can fail: one observation's last bit is a difference only where bit for
    bit is asked; another failure is one everywhere."""
    expected = GOLDEN["single/paper/scenario/random"]
    moved = {name: value.copy() for name, value in expected.items()}
    moved["obs"][5, 0] = np.nextafter(moved["obs"][5, 0], np.float32(np.inf))
    assert differences(expected, moved, bit_for_bit=False) == []
    assert differences(expected, moved, bit_for_bit=True) == ["obs not bit for bit at [[5, 0]]"]
    moved["failure"][0] = "collision"
    assert differences(expected, moved, bit_for_bit=False)[0].startswith("failure:")
