"""Configuration values that a run cannot survive are refused when the file is read.

Each case here was once accepted by validation and then failed, hung or blew up memory later: a
degenerate camera, unbounded numbers (noise, sizes, periods, the episode's step count), a target
start out of any reach, names that are not names (a scenario's ``name``, or a file name under
``configs/scenarios/``), a loop that cannot end (``jink_interval``), YAML that expands without
bound (an alias bomb, a huge file), duplicated keys, a suite whose reference is none of its
agents, a capture box the target can start inside. Every refusal is one line naming the file, the
key(s), the bad value and what is valid, raised as the loader's error (``ConfigError``,
``SuiteError``); the CLIs turn it into exit status 2 before any episode.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from capture_bench import __main__ as listing
from capture_bench.evaluation import pipeline
from capture_bench.evaluation.cli import main as evaluate
from capture_bench.evaluation.errors import SuiteError
from capture_bench.evaluation.pipeline import EvaluationConfig, plan_evaluation
from capture_bench.evaluation.running.suites import load_suite
from capture_bench.sim import kinematics, target_motion
from capture_bench.task import scenarios
from capture_bench.task.scenarios import (
    ConfigError,
    TargetConfig,
    invalid_scenarios,
    list_scenarios,
    load_scenario,
)
from capture_bench.training.config.hyperparameters import load_hyperparameters

SHIPPED = scenarios.SCENARIO_DIR
NAME_RULE = "lowercase letters, digits and _"
ONE_LINE = 300  # characters: what a one-line message stays under, whatever the file holds


def _scenario(tmp_path: Path, text: str, name: str = "limits.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _refused(path: Path, *expected: str) -> str:
    with pytest.raises(ConfigError) as raised:
        load_scenario(path)
    message = str(raised.value)
    assert message.startswith(f"{path}: ") and "\n" not in message, message
    for text in expected:
        assert text in message, message
    return message


# -- 1. the camera ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "look_at",
    [
        [0.45, -1.2, 0.40],  # the position itself
        [0.45, -1.2005, 0.40],  # 0.5 mm away
        [0.45, -1.2, -0.5],  # straight below: no camera z-axis
        [0.45, -1.2, 2.0],  # straight above
    ],
)
def test_a_camera_looking_at_its_own_position_or_straight_down_is_refused(tmp_path, look_at):
    path = _scenario(tmp_path, f"camera:\n  position: [0.45, -1.2, 0.40]\n  look_at: {look_at}\n")
    _refused(path, "keys 'camera.look_at' and 'camera.position'", "not valid; expected")


def test_a_camera_looking_a_little_off_vertical_or_2_mm_away_is_accepted(tmp_path):
    near = _scenario(tmp_path, "camera:\n  look_at: [0.45, -1.198, 0.40]\n", "near.yaml")
    assert load_scenario(near).camera.look_at == (0.45, -1.198, 0.40)
    tilted = _scenario(tmp_path, "camera:\n  look_at: [0.46, -1.2, -0.5]\n", "tilted.yaml")
    assert load_scenario(tilted).camera.model() is not None


# -- 2. numbers without a physical bound --------------------------------------------------------
def test_camera_noise_px_1e300_is_refused_with_its_range(tmp_path):
    path = _scenario(tmp_path, "camera:\n  noise_px: 1e300\n")
    with pytest.raises(ConfigError) as raised:
        load_scenario(path)
    # YAML 1.1 reads 1e300 (no dot) as the string '1e300'
    assert str(raised.value) == (
        f"{path}: key 'camera.noise_px': '1e300' is not valid; expected a number in [0, 100]"
    )


@pytest.mark.parametrize(
    ("key", "value", "valid"),
    [
        ("camera.resolution", "[1000000000, 960]", "whole numbers, each in [1, 8192]"),
        ("camera.focal_length", "1.0e300", "in [0.0001, 1]"),
        ("camera.pixel_pitch", "1.0e300", "in [1e-07, 0.0001]"),
        ("camera.marker_radius", "1.0e300", "in (0, 0.05]"),
        ("camera.light_intensity", "1.0e300", "in [0, 10]"),
        ("camera.light_direction", "[1.0e300, 1.0e300, 1.0e300]", "in [-10, 10]"),
        ("camera.image_noise", "1.0e300", "in [0, 255]"),
        ("camera.exposure", "1.0e300", "in [0, 1]"),
        ("camera.psf_sigma", "1.0e300", "in [0, 5]"),
        ("camera.latency_frames", "1000000000000", "in [0, 100]"),
        ("camera.position", "[1.0e300, 0, 0]", "in [-10, 10]"),
        ("estimator.sigma_acceleration", "1.0e300", "in (0, 100]"),
        ("estimator.sigma_angular_acceleration", "1.0e300", "in (0, 100]"),
        ("target.speed", "[1.0e300, 1.0e300]", "in [0, 1]"),
        ("target.tumble_rate_deg", "[1.0e300, 1.0e300]", "in [0, 360]"),
        ("target.capture_offset", "[1.0e300, 1.0e300]", "in [0, 1]"),
        ("target.circle_radius", "[0, 0]", "in [0.001, 1]"),  # speed / radius: a division by 0
        ("target.circle_speed", "[1.0e300, 1.0e300]", "in [0, 1]"),
        ("target.jink_acceleration", "[1.0e300, 1.0e300]", "in [0, 10]"),
        ("capture_tolerance", "1.0e300", "in (0, 0.1]"),
    ],
)
def test_an_unbounded_number_is_refused_with_its_valid_range(tmp_path, key, value, valid):
    section, _, leaf = key.rpartition(".")
    text = f"{section}:\n  {leaf}: {value}\n" if section else f"{leaf}: {value}\n"
    _refused(_scenario(tmp_path, text), f"key '{key}': ", "is not valid; expected", valid)


# -- 3. the episode's steps ---------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("control:\n  episode_limit: 1.0e+12\n", "key 'control.episode_limit': 1000000000000.0"),
        ("control:\n  period: 1.0e-12\n", "key 'control.period': 1e-12"),
        (
            "control:\n  episode_limit: 3600\n  period: 0.001\n",
            "keys 'control.episode_limit' and 'control.period'",
        ),
        (  # the shortest real period: 0.05 (1 - 0.9) s
            "control:\n  episode_limit: 600\n  period: 0.05\n  period_jitter: 0.9\n",
            "keys 'control.episode_limit' and 'control.period'",
        ),
    ],
)
def test_an_episode_of_more_than_100000_steps_is_refused(tmp_path, text, expected):
    message = _refused(_scenario(tmp_path, text), expected, "expected")
    if "keys" in expected:
        assert "at most 100000 steps" in message


def test_the_longest_episode_allowed_loads(tmp_path):
    path = _scenario(tmp_path, "control:\n  episode_limit: 3600\n  period: 0.05\n")
    assert load_scenario(path).control.episode_limit == 3600


# -- 4. the target's start ----------------------------------------------------------------------
def test_an_initial_offset_beyond_the_arms_reach_is_refused(tmp_path):
    path = _scenario(tmp_path, "target:\n  initial_offset: [1000000.0, 1000000.0]\n")
    _refused(path, "key 'target.initial_offset': [1000000.0, 1000000.0] is not valid", "[0, 1.4]")


def test_the_largest_initial_offset_is_farther_than_any_point_the_arm_reaches():
    """Every joint vector inside the limits (a 2-degree grid, the limits included) puts the
    end-effector closer to its home position than the largest offset allowed, which is less
    than 5 cm beyond the farthest."""
    lo, hi = np.degrees(kinematics.JOINT_LOWER), np.degrees(kinematics.JOINT_UPPER)
    axes = [np.radians(np.arange(a, b + 1.0, 2.0)) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    home = kinematics.forward_kinematics(kinematics.HOME)
    farthest = np.linalg.norm(kinematics.forward_kinematics(grid) - home, axis=1).max()
    assert 1.3 < farthest < scenarios.MAX_INITIAL_OFFSET < farthest + 0.05


# -- 5. a scenario's name -----------------------------------------------------------------------
@pytest.mark.parametrize("name", ["../../etc/x", "My Scenario", "", "_x", "paper-2", "x" * 65])
def test_a_name_that_is_not_an_identifier_is_refused(tmp_path, name):
    path = _scenario(tmp_path, f"name: {name!r}\n")
    _refused(path, "key 'name': ", "is not valid; expected", NAME_RULE)


def test_a_shipped_scenario_is_found_by_name_only_never_by_a_path():
    with pytest.raises(ConfigError, match=r"unknown scenario '\.\./scenarios/paper'"):
        load_scenario("../scenarios/paper")


# -- 6. a file name under configs/scenarios/ that is not a name ---------------------------------
@pytest.fixture
def scenario_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A scenario folder holding the shipped paper.yaml and two copies whose file names have a
    space, one of them naming itself validly."""
    folder = tmp_path / "scenarios"
    folder.mkdir()
    shutil.copy(SHIPPED / "paper.yaml", folder / "paper.yaml")
    shutil.copy(SHIPPED / "paper.yaml", folder / "my copy.yaml")
    text = (SHIPPED / "paper.yaml").read_text()
    (folder / "named copy.yaml").write_text(f"name: named_copy\n{text}")
    monkeypatch.setattr(scenarios, "SCENARIO_DIR", folder)
    monkeypatch.setattr(pipeline, "SCENARIO_DIR", folder)
    return folder


def test_a_scenario_file_whose_name_is_not_a_name_is_listed_invalid(scenario_dir):
    assert list_scenarios() == list_scenarios(camera="analytic") == ["paper"]
    invalid = invalid_scenarios()
    assert sorted(invalid) == ["my copy", "named copy"]
    for stem, message in invalid.items():
        assert message.startswith(f"{scenario_dir / (stem + '.yaml')}: the file name {stem!r}")
        assert NAME_RULE in message and "\n" not in message
        with pytest.raises(ConfigError) as raised:
            load_scenario(stem)
        assert str(raised.value) == message
    lines = listing.list_everything()
    at = lines.index("invalid scenario files (skipped; using one raises this error):")
    assert [line.split()[0] for line in lines[at + 1 : at + 3]] == ["my", "named"]


# -- 7. loops that cannot end -------------------------------------------------------------------
@pytest.mark.parametrize("interval", ["[0, 0]", "[-1, 0.5]", "[1.0e-300, 1.0e-300]"])
def test_a_jink_interval_without_a_positive_minimum_is_refused(tmp_path, interval):
    path = _scenario(tmp_path, f"target:\n  motion: evasive\n  jink_interval: {interval}\n")
    _refused(path, "key 'target.jink_interval'", "in [0.001, 3600]")


def test_more_than_100000_jinks_in_an_episode_are_refused(tmp_path):
    text = (
        "control:\n  episode_limit: 3600\n  period: 0.05\n"
        "target:\n  motion: evasive\n  jink_interval: [0.01, 0.02]\n"
    )
    message = _refused(_scenario(tmp_path, text), "keys 'target.jink_interval' and ")
    assert "control.episode_limit" in message and "at most 100000" in message
    drift = _scenario(tmp_path, text.replace("evasive", "drift"), "drift.yaml")
    assert load_scenario(drift).target.jink_interval == (0.01, 0.02)  # never drawn: no jinks


class _CountingRng:
    """A generator that stops a loop that would not end: AssertionError after many draws."""

    def __init__(self) -> None:
        self._rng = np.random.default_rng(0)
        self.draws = 0

    def __getattr__(self, name: str):
        method = getattr(self._rng, name)

        def counted(*args, **kwargs):
            self.draws += 1
            assert self.draws < 200_000, "the jink schedule does not end"
            return method(*args, **kwargs)

        return counted


@pytest.mark.parametrize("interval", [(0.0, 0.0), (1e-300, 1e-300)])
def test_sampling_an_endless_jink_schedule_raises_instead_of_looping(interval):
    config = TargetConfig(motion="evasive", jink_interval=interval)
    with pytest.raises(ValueError, match="jink_interval"):
        target_motion.sample_trajectory(config, _CountingRng(), np.zeros(3), horizon=10.0)


# -- 8. values that expand without bound --------------------------------------------------------
def _alias_bomb(levels: int) -> str:
    """A YAML list of anchored lists, each holding nine aliases of the one before: ``levels``
    levels hold 9**levels strings once the aliases are followed (9: the billion laughs)."""
    items = ["&l0 [" + ", ".join(["lol"] * 9) + "]"]
    items += [f"&l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]" for i in range(1, levels)]
    return "[" + ", ".join(items) + "]"


@pytest.mark.parametrize(
    ("text", "error", "key"),
    [
        ("description: {bomb}\n", ConfigError, "key 'description'"),
        ("camera: {bomb}\n", ConfigError, "key 'camera' must be a mapping"),
        ("camera:\n  noise_px: {bomb}\n", ConfigError, "key 'camera.noise_px'"),
    ],
)
@pytest.mark.parametrize("levels", [6, 9])
def test_an_alias_bomb_under_a_known_key_gives_a_short_message(tmp_path, text, error, key, levels):
    path = _scenario(tmp_path, text.format(bomb=_alias_bomb(levels)))
    with pytest.raises(error) as raised:
        load_scenario(path)
    message = str(raised.value)
    assert message.startswith(f"{path}: {key}") and "lol" in message
    assert len(message) < ONE_LINE and "\n" not in message, message[:ONE_LINE]


def test_an_alias_bomb_in_a_suite_or_a_long_value_gives_a_short_message(tmp_path):
    suite = tmp_path / "bomb.yaml"
    suite.write_text(f"agents: {_alias_bomb(9)}\nscenarios: [paper]\nepisodes: 1\n")
    with pytest.raises(SuiteError) as raised:
        load_suite(suite)
    assert "key 'agents'" in str(raised.value) and len(str(raised.value)) < ONE_LINE
    long = _scenario(tmp_path, f"camera:\n  noise_px: {'x' * 500_000}\n", "long.yaml")
    message = _refused(long, "key 'camera.noise_px': 'xxx")
    assert len(message) < ONE_LINE


@pytest.mark.parametrize(
    "text",
    [
        "{bomb}\n",
        "policy_kwargs:\n  features_extractor: {bomb}\n",
        "{{{bomb}: 1}}\n",
    ],
)
def test_an_alias_bomb_in_an_algorithm_config_gives_a_short_message(tmp_path, text):
    algo = tmp_path / "ppo.yaml"
    algo.write_text(text.format(bomb=_alias_bomb(9)))
    with pytest.raises(ConfigError) as raised:
        load_hyperparameters("ppo", algo)
    assert len(str(raised.value)) < ONE_LINE, str(raised.value)[:ONE_LINE]


# -- 9. the size of a file ----------------------------------------------------------------------
def test_a_file_over_1_mib_is_refused_before_it_is_read(tmp_path, monkeypatch):
    big = tmp_path / "big.yaml"
    with big.open("wb") as file:
        file.truncate(2 << 20)  # sparse: 2 MiB of nothing on disk

    def no_reading(*args, **kwargs):
        raise AssertionError("the file was read")

    monkeypatch.setattr(Path, "read_bytes", no_reading)
    monkeypatch.setattr(Path, "open", no_reading)
    expected = (
        f"{big}: the file's size, 2097152 bytes, is not valid; expected at most 1048576 bytes "
        "(1 MiB) for a configuration file"
    )
    for load, error in (
        (load_scenario, ConfigError),
        (load_suite, SuiteError),
        (lambda p: load_hyperparameters("ppo", p), ConfigError),
    ):
        with pytest.raises(error) as raised:
            load(big)
        assert str(raised.value) == expected


# -- 10. duplicated keys ------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "key", "lines"),
    [
        ("control:\n  period: 0.05\n  period: 0.1\n", "'period'", "lines 2 and 3"),
        ("capture_tolerance: 0.001\nlost_after: 1\ncapture_tolerance: 0.002\n", "'capture_tolerance'", "lines 1 and 3"),
        ("camera: {noise_px: 1, noise_px: 2}\n", "'noise_px'", "lines 1 and 1"),
    ],
)  # fmt: skip
def test_a_key_given_twice_is_refused_with_its_lines(tmp_path, text, key, lines):
    path = _scenario(tmp_path, text)
    message = _refused(path, f"key {key} is given twice in one mapping ({lines})")
    assert message.endswith("expected each key once")


def test_a_key_given_twice_in_a_suite_or_an_algorithm_config_is_refused(tmp_path):
    suite = tmp_path / "twice.yaml"
    suite.write_text("agents: [hold]\nscenarios: [paper]\nepisodes: 1\nepisodes: 2\n")
    with pytest.raises(SuiteError, match=r"key 'episodes' is given twice .*\(lines 3 and 4\)"):
        load_suite(suite)
    algo = tmp_path / "ppo.yaml"
    algo.write_text("n_envs: 1\ntotal_timesteps: 64\ngamma: 0.9\ngamma: 0.99\n")
    with pytest.raises(ConfigError, match=r"key 'gamma' is given twice .*\(lines 3 and 4\)"):
        load_hyperparameters("ppo", algo)


def test_a_merged_key_may_be_overridden_once(tmp_path):
    path = _scenario(tmp_path, "camera: {<<: {noise_px: 1.0, dropout: 0.1}, noise_px: 2.0}\n")
    camera = load_scenario(path).camera
    assert (camera.noise_px, camera.dropout) == (2.0, 0.1)


# -- 11. a suite's reference --------------------------------------------------------------------
def test_a_suite_whose_reference_is_none_of_its_agents_is_refused(tmp_path, capsys):
    suite = tmp_path / "mine.yaml"
    suite.write_text(
        "agents: [hold, random]\nscenarios: [paper]\nepisodes: 1\nreference: incremental_ik\n"
    )
    out = tmp_path / "out"
    assert evaluate(["--suite", str(suite), "--workers", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("evaluate.py: error: "), err
    assert f"{suite}: key 'reference': 'incremental_ik' is not valid" in err
    assert "expected one of the suite's agents: hold, random" in err
    assert not out.exists()


def test_agents_given_on_the_command_line_keep_the_suites_reference_as_it_was(tmp_path):
    suite = tmp_path / "mine.yaml"
    suite.write_text("agents: [hold]\nscenarios: [paper]\nepisodes: 1\nreference: hold\n")
    out = tmp_path / "out"
    for agents in (["random"], ["hold", "random"]):  # without the reference: not paired
        config = EvaluationConfig(suite=str(suite), agents=agents, workers=1, out=out)
        assert plan_evaluation(config).suite.reference == "hold"
    default = tmp_path / "plain.yaml"  # no reference key: incremental_ik, not paired with hold
    default.write_text("agents: [hold]\nscenarios: [paper]\nepisodes: 1\n")
    plan = plan_evaluation(EvaluationConfig(suite=str(default), workers=1, out=out))
    assert plan.suite.reference == "incremental_ik"
    assert not out.exists()


# -- 12. the capture box against the target's start ---------------------------------------------
def test_a_capture_box_the_target_can_start_inside_is_refused(tmp_path):
    path = _scenario(tmp_path, "capture_tolerance: 0.1\ntarget:\n  initial_offset: [0.17, 0.3]\n")
    message = _refused(path, "keys 'target.initial_offset' and 'capture_tolerance'")
    assert "sqrt(3) x capture_tolerance (0.1732 m)" in message
    # why sqrt(3): on the box's diagonal a start 0.17 m away is inside every component's 0.1 m
    start = 0.17 * np.ones(3) / math.sqrt(3.0)
    assert (np.abs(start) < 0.1).all()
    path.write_text("capture_tolerance: 0.1\ntarget:\n  initial_offset: [0.18, 0.3]\n")
    assert load_scenario(path).capture_tolerance == 0.1


def test_a_zero_initial_offset_is_refused_by_any_tolerance(tmp_path):
    path = _scenario(tmp_path, "target:\n  initial_offset: [0.0, 0.3]\n")
    _refused(path, "keys 'target.initial_offset' and 'capture_tolerance'")


# -- every case at the command line -------------------------------------------------------------
@pytest.mark.parametrize(
    "text",
    [
        "camera:\n  look_at: [0.45, -1.2, 0.40]\n",
        "target:\n  motion: evasive\n  jink_interval: [0, 0]\n",
        "control:\n  period: 1.0e-12\n",
        "capture_tolerance: 0.05\ntarget:\n  initial_offset: [0.05, 0.3]\n",
    ],
)
def test_evaluate_refuses_in_one_line_with_exit_status_2_and_writes_nothing(tmp_path, capsys, text):
    path = _scenario(tmp_path, text)
    out = tmp_path / "out"
    argv = ["--agents", "hold", "--scenarios", str(path), "--workers", "1", "--out", str(out)]
    assert evaluate(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"evaluate.py: error: {path}: ") and "\n" not in err, err
    assert not out.exists()
