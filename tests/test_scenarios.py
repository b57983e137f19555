"""Scenario files: every shipped one validates; bad input names file, key, value and what is valid."""

import pytest

from capture_bench.task.scenarios import ConfigError, list_scenarios, load_scenario

REQUIRED = {"paper", "drift", "circular", "tumbling", "jitter", "noisy", "grasp"}


def test_all_required_scenarios_ship_and_validate():
    assert REQUIRED <= set(list_scenarios())
    for name in list_scenarios():
        scenario = load_scenario(name)
        assert scenario.name == name
        assert len(scenario.evaluation_seeds) >= 100
        assert not set(scenario.evaluation_seeds) & set(scenario.training_seeds)


def test_unknown_scenario_lists_the_valid_ones():
    with pytest.raises(ConfigError, match="unknown scenario 'nope'; valid: .*paper"):
        load_scenario("nope")


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("target: [unclosed", "invalid YAML"),
        ("camera:\n  noise_pix: 1.0\n", "unknown key 'camera.noise_pix'; valid keys: position"),
        (
            "camera:\n  noise_px: -1\n",
            r"key 'camera.noise_px': -1 is not valid; expected a number in \[0, 100\]",
        ),
        ("target:\n  motion: zigzag\n", "'zigzag' is not valid; expected one of drift, circular"),
        (
            "target:\n  speed: [0.05, 0.01]\n",
            r"is not valid; expected a list of 2 numbers \[low, high\] with low <= high",
        ),
        (
            "control:\n  period: fast\n",
            r"'fast' is not valid; expected a number in \[0.001, 1\]",
        ),
        ("- just\n- a list\n", "expected a mapping"),
        (
            "capture:\n  hold: -0.1\n",
            r"key 'capture.hold': -0.1 is not valid; expected a number >= 0",
        ),
        (
            "capture:\n  hold: 10.0\n",
            r"key 'capture.hold': 10.0 is not valid; expected a number >= 0 and less than "
            r"control.episode_limit \(10.0 s\)",
        ),
    ],
)
def test_bad_files_name_file_key_value_and_valid_choices(tmp_path, text, pattern):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=pattern) as err:
        load_scenario(path)
    assert str(path) in str(err.value)


def test_override_is_validated():
    with pytest.raises(ConfigError, match="expected one of ekf, photogrammetry, truth"):
        load_scenario("paper").replace(estimator={"source": "oracle"})
