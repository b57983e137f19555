"""One validator for scenario, suite and algorithm files: the rules, and one message shape."""

from __future__ import annotations

import math

import pytest

from capture_bench.evaluation.errors import SuiteError
from capture_bench.evaluation.running.suites import load_suite
from capture_bench.task.scenarios import load_scenario
from capture_bench.training.config.hyperparameters import load_hyperparameters
from capture_bench.validation import ConfigError, Rule, check_mapping


@pytest.mark.parametrize(
    ("rule", "value", "canonical"),
    [
        (Rule("int", 1), 3, 3),
        (Rule("int", 0), 10**30, 10**30),  # exact however large
        (Rule("int", 1), 4.0, 4),
        (Rule("float", 0.0, 1.0), "3e-1", 0.3),  # YAML reads 3e-1 as a string
        (Rule("float", 0.0, low_inclusive=False), 1e-12, 1e-12),
        (Rule("numbers", length=2), [0.1, 0.2], (0.1, 0.2)),
        (Rule("numbers", length=2, item="int"), [1280, 960], (1280, 960)),
        (Rule("names", choices=("all",)), "all", ("all",)),
        (Rule("names"), ["a", "b", "a"], ("a", "b")),
        (Rule("schedule"), "lin_3e-4", "lin_3e-4"),
        (Rule("float_or_auto"), "auto_0.1", "auto_0.1"),
        (Rule("optional_float", 0.0), None, None),
        (Rule("layers", choices=("pi", "vf")), {"pi": [64], "vf": [64, 64]}, None),
        (Rule("weights"), {"grasp": 7, "paper": "0.5"}, {"grasp": 7.0, "paper": 0.5}),
    ],
)
def test_a_valid_value_comes_back_canonical(rule, value, canonical):
    out = rule.check(value, "f.yaml: key 'k'")
    assert out == (value if canonical is None else canonical)
    assert type(out) is type(value if canonical is None else canonical)


@pytest.mark.parametrize(
    ("rule", "value"),
    [
        (Rule("int", 1), True),  # a bool is not a number
        (Rule("int", 1), 0),
        (Rule("int", 1), 1.5),
        (Rule("int", 1), "1e400"),
        (Rule("float", 0.0, 1.0), math.nan),
        (Rule("float", 0.0, 1.0), math.inf),
        (Rule("float", 0.0, low_inclusive=False), 0.0),
        (Rule("float"), [1.0]),
        (Rule("numbers", length=2), [0.2, 0.1]),  # low > high
        (Rule("numbers", length=2), [0.1]),
        (Rule("numbers", length=2, item="int"), [1280, 960.5]),
        (Rule("names"), []),
        (Rule("names"), ["a", ""]),
        (Rule("names"), "all"),  # only where "all" is a choice
        (Rule("choice", choices=("a",)), ["a"]),  # unhashable: refused, not a TypeError
        (Rule("schedule"), "lin_0"),
        (Rule("schedule"), -1),
        (Rule("layers", choices=("pi",)), {"qf": [64]}),
        (Rule("layers"), [64, True]),
        (Rule("weights"), {}),
        (Rule("weights"), {"grasp": 0}),
        (Rule("weights"), {"grasp": True}),
        (Rule("weights"), {"": 1.0}),
        (Rule("weights"), ["grasp"]),
    ],
)
def test_an_invalid_value_is_one_message_naming_where_what_and_what_is_valid(rule, value):
    with pytest.raises(ConfigError) as err:
        rule.check(value, "f.yaml: key 'k'")
    assert str(err.value) == f"f.yaml: key 'k': {value!r} is not valid; expected {rule.describe()}"


def test_nested_keys_are_dotted_and_the_error_type_is_the_callers():
    schema = {"a": {"b": Rule("int", 0)}}
    with pytest.raises(SuiteError, match=r"^s.yaml: key 'a.b': -1 is not valid; expected"):
        check_mapping({"a": {"b": -1}}, schema, "s.yaml", error=SuiteError)
    with pytest.raises(SuiteError, match=r"^s.yaml: unknown key 'a.c'; valid keys: b$"):
        check_mapping({"a": {"c": 1}}, schema, "s.yaml", error=SuiteError)
    with pytest.raises(SuiteError, match=r"^s.yaml: key 'a' must be a mapping"):
        check_mapping({"a": 3}, schema, "s.yaml", error=SuiteError)
    with pytest.raises(SuiteError, match=r"^s.yaml: missing key 'a' \(a mapping\)"):
        check_mapping({}, schema, "s.yaml", error=SuiteError, required={"a": "a mapping"})


def test_the_three_kinds_of_file_give_the_same_message_shape(tmp_path):
    scenario, suite, algo = tmp_path / "sc.yaml", tmp_path / "su.yaml", tmp_path / "al.yaml"
    scenario.write_text("control:\n  period: -1\n")
    suite.write_text("agents: [hold]\nscenarios: [paper]\nepisodes: -1\n")
    algo.write_text("n_envs: 1\ntotal_timesteps: 64\ngamma: 2\n")
    messages = []
    for load, path, error in (
        (load_scenario, scenario, ConfigError),
        (load_suite, suite, SuiteError),
        (lambda p: load_hyperparameters("ppo", p), algo, ConfigError),
    ):
        with pytest.raises(error) as err:
            load(path)
        messages.append(str(err.value))
    assert messages == [
        f"{scenario}: key 'control.period': -1 is not valid; expected a number in [0.001, 1]",
        f"{suite}: key 'episodes': -1 is not valid; expected a whole number >= 1",
        f"{algo}: key 'gamma': 2 is not valid; expected a number in [0, 1]",
    ]
    for path in (scenario, suite, algo):
        path.write_text("[1, 2]\n")
    with pytest.raises(ConfigError, match=f"^{scenario}: expected a mapping of scenario keys"):
        load_scenario(scenario)
    with pytest.raises(SuiteError, match=f"^{suite}: expected a mapping of suite keys"):
        load_suite(suite)
    with pytest.raises(ConfigError, match=f"^{algo}: expected a mapping of hyper-parameters"):
        load_hyperparameters("ppo", algo)
