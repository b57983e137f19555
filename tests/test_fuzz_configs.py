"""Fuzzing the three YAML loaders (issue 10, item 7): scenario, suite and algorithm files.

Each test writes a generated file under ``tmp_path`` and loads it. The only exception a loader may
raise is its documented one ([`ConfigError`][capture_bench.ConfigError] for scenarios and hyper-parameters,
`SuiteError` for suites), and its message names the file and the key at fault; a valid
mapping builds the object with exactly the values written. Documents start valid and get a few
mutations, each known to be invalid (a wrong type, a value out of range, NaN, a huge number, an
unknown or non-string key, a section that is not a mapping), so every test knows which answer is
right and which key the message must name. Hypothesis runs derandomised and without a database,
so CI sees the same inputs every run and nothing is written into the repository.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from capture_bench.evaluation.errors import SuiteError
from capture_bench.evaluation.running.suites import Suite, load_suite
from capture_bench.task.scenarios import ConfigError, Scenario, SeedConfig, load_scenario
from capture_bench.training.config.hyperparameters import (
    ALGO_KEYS,
    ALGORITHMS,
    IMITATION_DEFAULTS,
    POLICY_KWARGS,
    TRAINING_KEYS,
    load_hyperparameters,
)
from capture_bench.validation import Rule

FUZZ = settings(
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

# -- values ------------------------------------------------------------------------------------
HUGE_INT = st.integers(min_value=2**1024 - 2**970, max_value=2**1100)  # float() overflows
NON_FINITE = st.sampled_from([math.nan, math.inf, -math.inf])
JUNK_TEXT = st.text(st.characters(exclude_categories=("Cs",)), max_size=12)
NON_NUMBER_SCALARS = st.one_of(
    st.booleans(),
    st.none(),
    JUNK_TEXT.filter(lambda s: not _parses_as_number(s)),
    st.dictionaries(st.sampled_from(["a", "b"]), st.integers(0, 9), max_size=2),
)
NON_NUMBERS = st.one_of(NON_NUMBER_SCALARS, st.lists(st.integers(0, 9), max_size=3))
NON_STRINGS = st.one_of(
    st.integers(), st.floats(), st.booleans(), st.none(), st.lists(JUNK_TEXT, max_size=2)
)
SCALARS = st.one_of(st.integers(), st.floats(), st.booleans(), st.none())
NOT_A_MAPPING = st.one_of(
    st.none(), st.integers(), JUNK_TEXT, st.lists(st.integers(0, 9), max_size=3)
)


def _parses_as_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _real(low: float, high: float) -> st.SearchStrategy[float]:
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


def _kind(valid: st.SearchStrategy, invalid: st.SearchStrategy) -> dict[str, Any]:
    return {"valid": valid, "invalid": invalid}


def _positive(high: float = 1e6) -> dict[str, Any]:
    return _kind(
        st.one_of(_real(1e-9, high), st.integers(1, 10**6)),
        st.one_of(_real(-1e6, 0.0), NON_FINITE, HUGE_INT, NON_NUMBERS),
    )


def _fraction(high: float) -> dict[str, Any]:
    return _kind(
        _real(0.0, high),
        st.one_of(_real(-1e6, -1e-9), _real(high + 1e-6, 1e6), NON_FINITE, HUGE_INT, NON_NUMBERS),
    )


def _whole(low: int, high: int | None = None) -> dict[str, Any]:
    above = [] if high is None else [st.integers(high + 1, 10 * high)]
    return _kind(
        st.one_of(
            st.integers(low, high or 10**6), st.integers(low, min(high or 1000, 1000)).map(float)
        ),
        st.one_of(
            st.integers(-(10**6), low - 1),
            *above,
            _real(low + 0.01, 1e3).filter(lambda x: not x.is_integer()),
            NON_FINITE,
            NON_NUMBERS,
        ),
    )


def _vector(n: int, number: st.SearchStrategy) -> dict[str, Any]:
    return _kind(
        st.lists(number, min_size=n, max_size=n),
        st.one_of(
            st.lists(number, max_size=5).filter(lambda v: len(v) != n),
            st.lists(st.one_of(number, NON_FINITE), min_size=n, max_size=n).filter(
                lambda v: not all(math.isfinite(x) for x in v)
            ),
            st.lists(st.one_of(number, JUNK_TEXT, st.none()), min_size=n, max_size=n).filter(
                lambda v: any(isinstance(x, str) or x is None for x in v)
            ),
            NON_NUMBER_SCALARS,
        ),
    )


def _bounded(low: float, high: float, low_inclusive: bool = True) -> dict[str, Any]:
    """A number in [low, high] ((low, high] unless ``low_inclusive``)."""
    above = _real(high * (1 + 1e-6) + 1e-9, max(10 * high, 1e6))
    below = _real(-1e6, low - 1e-9) if low_inclusive else _real(-1e6, low)
    valid = _real(low, high) if low_inclusive else _real(low, high).filter(lambda x: x > low)
    return _kind(valid, st.one_of(below, above, NON_FINITE, HUGE_INT, NON_NUMBERS))


def _range(low: float, high: float, limit_low: float, limit_high: float) -> dict[str, Any]:
    """A [low, high] pair drawn inside [low, high] (the key's valid range is [limit_low,
    limit_high]); invalid: a wrong shape, reversed, or an end outside the valid range."""
    pair = st.lists(_real(low, high), min_size=2, max_size=2)
    shape = _vector(2, _real(low, high))
    outside = st.lists(
        st.one_of(_real(-1e6, limit_low - 1e-6), _real(limit_high + 1e-6, 1e6)),
        min_size=1,
        max_size=1,
    )
    mixed = st.tuples(outside, _real(low, high)).map(lambda v: sorted([v[0][0], v[1]]))
    reversed_pair = pair.filter(lambda v: v[0] > v[1])
    return _kind(pair.map(sorted), st.one_of(shape["invalid"], reversed_pair, mixed))


def _point(y_low: float, y_high: float) -> dict[str, Any]:
    """A point in [-5, 5]^3 with y in [y_low, y_high]; invalid: a wrong shape, a non-number, or
    a coordinate outside [-10, 10]."""
    point = st.tuples(NUMBER3, _real(y_low, y_high), NUMBER3).map(list)
    far = st.lists(st.one_of(_real(10.001, 1e6), _real(-1e6, -10.001)), min_size=3, max_size=3)
    return _kind(point, st.one_of(_vector(3, NUMBER3)["invalid"], far))


def _choice(*choices: str) -> dict[str, Any]:
    others = st.one_of(
        JUNK_TEXT.filter(lambda s: s not in choices), st.sampled_from([c.upper() for c in choices])
    )
    return _kind(st.sampled_from(choices), st.one_of(others, NON_STRINGS))


TEXT = _kind(JUNK_TEXT, NON_STRINGS)
NAME = _kind(
    st.from_regex(r"[a-z][a-z0-9_]{0,20}", fullmatch=True),
    st.one_of(
        NON_STRINGS, st.sampled_from(["", "Paper", "../../etc/x", "a b", "_x", "1x", "x" * 65])
    ),
)
NUMBER3 = _real(-5.0, 5.0)
#: Every scenario key, as documented in capture_bench/task/scenarios.py (unit and valid range).
#: Valid values are drawn where the rules that tie keys together hold whatever else the mapping
#: says (tests/test_config_limits.py tests those rules): 1-50 s of steps of >= 0.01 s (a hold of
#: at most 0.9 s fits), the camera at y <= -2 looking at y >= -1, initial offsets >= 0.2 m and
#: tolerances <= 0.1 m.
SCENARIO_SPEC: dict[str, Any] = {
    "name": NAME,
    "description": TEXT,
    "capture_tolerance": _bounded(0.0, 0.1, low_inclusive=False),
    "lost_after": _positive(),
    "control": {
        "period": _kind(_real(0.01, 1.0), _bounded(0.001, 1.0)["invalid"]),
        "period_jitter": _fraction(0.9),
        "episode_limit": _kind(
            _real(1.0, 50.0), _bounded(0.0, 3600.0, low_inclusive=False)["invalid"]
        ),
    },
    "capture": {
        "hold": _kind(_real(0.0, 0.9), _bounded(0.0, 1e6)["invalid"]),
        "v_max": _kind(
            st.one_of(st.none(), _real(1e-3, 10.0)),
            _bounded(0.0, 10.0, low_inclusive=False)["invalid"].filter(lambda v: v is not None),
        ),
    },
    "ranked": _kind(st.booleans(), NON_STRINGS.filter(lambda v: not isinstance(v, bool))),
    "camera": {
        "position": _point(-5.0, -2.0),
        "look_at": _point(-1.0, 5.0),
        "focal_length": _bounded(1e-4, 1.0),
        "pixel_pitch": _bounded(1e-7, 1e-4),
        "resolution": _kind(
            st.lists(st.integers(1, 8192), min_size=2, max_size=2),
            st.one_of(
                _vector(2, st.integers(1, 5000))["invalid"],
                st.lists(st.integers(8193, 10**9), min_size=2, max_size=2),
            ),
        ),
        "noise_px": _bounded(0.0, 100.0),
        "dropout": _fraction(1.0),
        "latency_frames": _whole(0, high=100),
    },
    "estimator": {
        "source": _choice("ekf", "photogrammetry", "truth"),
        "sigma_acceleration": _bounded(0.0, 100.0, low_inclusive=False),
        "sigma_angular_acceleration": _bounded(0.0, 100.0, low_inclusive=False),
    },
    "target": {
        "motion": _choice("drift", "circular", "tumbling", "evasive"),
        "feature_points": _choice("non_coplanar", "coplanar_square"),
        "initial_offset": _range(0.2, 1.4, 0.0, 1.4),
        "speed": _range(0.0, 1.0, 0.0, 1.0),
        "tumble_rate_deg": _range(0.0, 360.0, 0.0, 360.0),
        "capture_offset": _range(0.0, 1.0, 0.0, 1.0),
        "circle_radius": _range(0.001, 1.0, 0.001, 1.0),
        "circle_speed": _range(0.0, 1.0, 0.0, 1.0),
        "jink_interval": _range(0.001, 3600.0, 0.001, 3600.0),
        "jink_acceleration": _range(0.0, 10.0, 0.0, 10.0),
    },
    "seeds": {
        "evaluation_start": _whole(0),
        "evaluation_count": _whole(1, high=100_000),  # every report lists them
        "training_start": _whole(0),
        "training_count": _whole(1),
    },
}
SECTIONS = [k for k, v in SCENARIO_SPEC.items() if "valid" not in v]
LEAVES = [
    (section, key) if section else (key,)
    for section, keys in [(None, [k for k in SCENARIO_SPEC if k not in SECTIONS])]
    + [(s, list(SCENARIO_SPEC[s])) for s in SECTIONS]
    for key in keys
]
UNKNOWN_KEYS = st.one_of(  # never two that YAML would read as one key (1 and true, 2 and 2.0)
    st.text(st.characters(categories=("L", "N")), min_size=1, max_size=10),
    st.integers().filter(lambda n: n not in (0, 1)),
    st.none(),
    st.booleans(),
    _real(-10.0, 10.0).filter(lambda x: not x.is_integer()),
)


def _spec(path: tuple[str, ...]) -> dict[str, Any]:
    spec = SCENARIO_SPEC
    for part in path:
        spec = spec[part]
    return spec


def _dotted(path: tuple[Any, ...]) -> str:
    return ".".join(str(p) for p in path)


@st.composite
def valid_scenarios(draw: st.DrawFn) -> dict[str, Any]:
    """A valid scenario mapping: a random subset of the keys, each with a valid value."""
    data: dict[str, Any] = {}
    for path in draw(st.lists(st.sampled_from(LEAVES), unique=True, max_size=len(LEAVES))):
        target = data if len(path) == 1 else data.setdefault(path[0], {})
        target[path[-1]] = draw(_spec(path)["valid"])
    for section in draw(st.lists(st.sampled_from(SECTIONS), unique=True)):
        data.setdefault(section, {})  # an empty section is valid: every key has a default
    return data


@st.composite
def broken_scenarios(draw: st.DrawFn) -> tuple[dict[str, Any], set[str]]:
    """A valid mapping with 1-3 invalid mutations; returns it and the dotted keys mutated."""
    data = draw(valid_scenarios())
    bad: set[str] = set()
    for _ in range(draw(st.integers(1, 3))):
        how = draw(st.sampled_from(["value", "value", "value", "unknown", "section"]))
        if how == "section":
            section = draw(st.sampled_from(SECTIONS))
            data[section] = draw(NOT_A_MAPPING)
            bad = {k for k in bad if k.split(".")[0] != section} | {section}
            continue
        path: tuple[Any, ...] = draw(st.sampled_from(LEAVES))
        if len(path) == 2 and not isinstance(data.get(path[0], {}), dict):
            continue  # that section is already broken
        target = data if len(path) == 1 else data.setdefault(path[0], {})
        if how == "unknown":
            known = _known_keys(path[:-1])
            key = draw(UNKNOWN_KEYS.filter(lambda k, known=known: k not in known))
            path = (*path[:-1], key)
            value = draw(st.one_of(st.integers(), JUNK_TEXT))
        else:
            value = draw(_spec(path)["invalid"])
        target[path[-1]] = value
        bad.add(_dotted(path))
    return data, bad


def _known_keys(section: tuple[str, ...]) -> set[Any]:
    return set(_spec(section)) if section else set(SCENARIO_SPEC)


def _write(tmp_path: Path, name: str, text: str) -> Path:
    """Write ``text`` as UTF-8; lone surrogates become bytes that are not UTF-8 (a Latin-1 file)."""
    path = tmp_path / name
    try:
        path.write_bytes(text.encode("utf-8", "surrogateescape"))
    except UnicodeEncodeError:
        path.write_bytes(text.encode("utf-8", "surrogatepass"))
    return path


def _names_one_of(message: str, keys: set[Any]) -> bool:
    """Whether ``message`` names one of ``keys`` (quoted, as the loaders write a key)."""
    return any(repr(k) in message or repr(str(k)) in message for k in keys)


def _dump(data: Any) -> str:
    return yaml.safe_dump(data, allow_unicode=True, sort_keys=False)


def _assert_built_as_written(scenario: Scenario, data: dict[str, Any], stem: str) -> None:
    assert scenario.name == data.get("name", stem)
    for path in LEAVES:
        section = data if len(path) == 1 else data.get(path[0], {})
        if path[-1] not in section:
            continue
        value = scenario if len(path) == 1 else getattr(scenario, path[0])
        got, want = getattr(value, path[-1]), section[path[-1]]
        assert got == (tuple(want) if isinstance(want, list) else want), _dotted(path)


@settings(FUZZ, max_examples=100)
@given(data=valid_scenarios())
@example(data={"seeds": {"evaluation_start": 2**1024, "training_count": 1e300}})
def test_a_valid_scenario_mapping_builds_with_the_values_written(tmp_path, data):
    path = _write(tmp_path, "fuzz_valid.yaml", _dump(data))
    if _seed_ranges_overlap(data.get("seeds", {})):  # every key valid, the ranges not disjoint
        with pytest.raises(ConfigError, match=r"key 'seeds': the training seeds .* overlap"):
            load_scenario(path)
        return
    _assert_built_as_written(load_scenario(path), data, "fuzz_valid")


def _seed_ranges_overlap(seeds: dict[str, Any]) -> bool:
    """Whether the training range meets the evaluation + validation range (the defaults for
    keys not given)."""
    s = {**dataclasses.asdict(SeedConfig()), **seeds}
    start, stop = s["evaluation_start"], s["evaluation_start"] + s["evaluation_count"]
    stop += s["validation_count"]
    return s["training_start"] < stop and start < s["training_start"] + s["training_count"]


@settings(FUZZ, max_examples=200)
@given(case=broken_scenarios())
@example(case=({"capture_tolerance": 10**400}, {"capture_tolerance"}))
@example(case=({1: 2, "x": 3}, {"1", "x"}))
@example(case=({"camera": {None: 1}}, {"camera.None"}))
def test_a_bad_scenario_key_is_a_config_error_naming_the_file_and_the_key(tmp_path, case):
    data, bad = case
    path = _write(tmp_path, "fuzz_bad.yaml", _dump(data))
    with pytest.raises(ConfigError) as raised:
        load_scenario(path)
    message = str(raised.value)
    assert str(path) in message and "\n" not in message
    assert _names_one_of(message, bad), (message, bad)


@settings(FUZZ, max_examples=40)
@given(data=st.one_of(NOT_A_MAPPING, st.lists(valid_scenarios(), min_size=1, max_size=2)))
def test_a_scenario_file_that_is_not_a_mapping_is_a_config_error_naming_the_file(tmp_path, data):
    path = _write(tmp_path, "fuzz_shape.yaml", _dump(data))
    with pytest.raises(ConfigError, match="fuzz_shape.yaml"):
        load_scenario(path)


# YAML that PyYAML's safe loader itself chokes on with ValueError, KeyError, AttributeError or
# RecursionError rather than a YAMLError: tagged scalars that do not parse, impossible dates.
HOSTILE_YAML = [
    "description: 2001-13-01\n",
    "lost_after: 2001-02-30 10:00:00\n",
    "lost_after: !!int abc\n",
    "lost_after: !!float abc\n",
    "name: !!bool maybe\n",
    "name: !!timestamp yesterday\n",
    "name: !!binary '%%%'\n",
    "name: !!python/object/apply:os.system ['echo pwned']\n",
    "camera: &a {position: *a}\n",
    "[" * 600,  # the parser's recursion limit (deeper costs PyYAML seconds, not more coverage)
    "control:\n  period: 0.05\n period: 0.1\n",
    "\x00\x01",
    "capture_tolerance: 1e-3\n",  # YAML 1.1 reads this as a string
    "description: caf\udce9\n",  # Latin-1, not UTF-8
]


@settings(FUZZ, max_examples=100)
@given(
    text=st.one_of(
        st.sampled_from(HOSTILE_YAML),
        st.text(max_size=200),
        st.builds(
            lambda doc, cut, junk: doc[:cut] + junk + doc[cut:],
            valid_scenarios().map(_dump),
            st.integers(0, 200),
            st.text(":-[]{}&*!|>'\"%@`#,? \n\t", max_size=6),
        ),
    )
)
def test_any_text_as_a_scenario_file_builds_or_is_a_config_error(tmp_path, text):
    path = _write(tmp_path, "fuzz_text.yaml", text)
    try:
        assert isinstance(load_scenario(path), Scenario)
    except ConfigError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)


# -- suites ------------------------------------------------------------------------------------
NAMES = st.lists(
    st.text(st.characters(categories=("L", "N", "P")), min_size=1, max_size=12),
    min_size=1,
    max_size=4,
)
SUITE_SPEC = {
    "description": TEXT,
    "agents": _kind(NAMES, st.one_of(st.just([]), JUNK_TEXT, SCALARS, st.lists(st.one_of(st.just(""), st.integers()), min_size=1, max_size=2))),
    "scenarios": _kind(st.one_of(NAMES, st.just("all")), st.one_of(st.just([]), JUNK_TEXT.filter(lambda s: s != "all"), SCALARS, st.lists(st.one_of(st.just(""), st.none()), min_size=1, max_size=2))),
    "episodes": _kind(st.integers(1, 10**6), st.one_of(st.integers(-(10**6), 0), st.floats(), st.booleans(), NON_NUMBERS, HUGE_INT.map(lambda n: -n))),
    "reference": _kind(JUNK_TEXT.filter(bool), st.one_of(st.just(""), NON_STRINGS)),
    "videos": _kind(st.booleans(), st.one_of(st.integers(0, 1), st.sampled_from(["true", "yes"]), st.none(), st.floats())),
}  # fmt: skip
REQUIRED_SUITE_KEYS = ("agents", "scenarios", "episodes")


@st.composite
def suites(draw: st.DrawFn) -> tuple[dict[str, Any], set[str]]:
    """A suite mapping and the keys made invalid (empty: a valid suite)."""
    optional = draw(st.lists(st.sampled_from(["description", "reference", "videos"]), unique=True))
    data = {k: draw(SUITE_SPEC[k]["valid"]) for k in [*REQUIRED_SUITE_KEYS, *optional]}
    bad: set[str] = set()
    for _ in range(draw(st.integers(0, 2))):
        how = draw(st.sampled_from(["value", "value", "missing", "unknown"]))
        if how == "unknown":
            key = draw(UNKNOWN_KEYS.filter(lambda k: k not in SUITE_SPEC))
            data[key] = draw(JUNK_TEXT)
        else:
            key = draw(st.sampled_from(list(SUITE_SPEC) if how == "value" else REQUIRED_SUITE_KEYS))
            if how == "missing":
                data.pop(key, None)
            else:
                data[key] = draw(SUITE_SPEC[key]["invalid"])
        bad.add(key)
    return data, bad


@settings(FUZZ, max_examples=120)
@given(case=suites())
@example(case=({"agents": ["a"], "scenarios": "all", "episodes": 1, 3: 4, "z": 1}, {3, "z"}))
def test_a_suite_file_loads_as_written_or_is_a_suite_error_naming_the_file_and_key(tmp_path, case):
    data, bad = case
    path = _write(tmp_path, "fuzz_suite.yaml", _dump(data))
    if not bad:
        suite = load_suite(path)
        assert isinstance(suite, Suite) and suite.name == "fuzz_suite"
        assert suite.agents == tuple(dict.fromkeys(data["agents"]))
        scenarios = data["scenarios"]
        assert suite.scenarios == (
            ("all",) if scenarios == "all" else tuple(dict.fromkeys(scenarios))
        )
        assert suite.episodes == data["episodes"]
        assert suite.description == data.get("description", "")
        assert suite.reference == data.get("reference", "incremental_ik")
        assert suite.videos is data.get("videos", True)
        return
    with pytest.raises(SuiteError) as raised:
        load_suite(path)
    message = str(raised.value)
    assert str(path) in message and "\n" not in message
    assert _names_one_of(message, bad), (message, bad)


@settings(FUZZ, max_examples=40)
@given(
    text=st.one_of(st.sampled_from(HOSTILE_YAML), st.text(max_size=120), NOT_A_MAPPING.map(_dump))
)
def test_any_text_as_a_suite_file_loads_or_is_a_suite_error(tmp_path, text):
    path = _write(tmp_path, "fuzz_suite_text.yaml", text)
    try:
        assert isinstance(load_suite(path), Suite)
    except SuiteError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)


# -- algorithm hyper-parameters ----------------------------------------------------------------
def _rule_values(rule: Rule) -> dict[str, Any]:
    """Valid and invalid values of one hyper-parameter rule (its documented meaning)."""
    low = rule.low if math.isfinite(rule.low) else -1e6
    high = rule.high if math.isfinite(rule.high) else 1e6
    if rule.kind == "int":
        return _kind(
            st.integers(int(low), min(int(high), 10**6)),
            st.one_of(st.integers(-(10**6), int(low) - 1), _real(low + 0.01, low + 100).filter(lambda x: not x.is_integer()), NON_FINITE, HUGE_INT, NON_NUMBERS),
        )  # fmt: skip
    if rule.kind == "float":
        outside = [_real(-1e6, low - 1e-3)] if math.isfinite(rule.low) else []
        outside += [_real(high + 1e-3, 1e7)] if math.isfinite(rule.high) else []
        if not rule.low_inclusive:  # (low, high]: low itself is invalid
            outside.append(st.just(low))
            return _kind(_real(low + 1e-6, high), st.one_of(*outside, NON_FINITE, NON_NUMBERS))
        return _kind(_real(low, high), st.one_of(*outside, NON_FINITE, HUGE_INT, NON_NUMBERS))
    if rule.kind == "optional_float":
        return _kind(
            st.one_of(st.none(), _real(low, high)),
            st.one_of(
                _real(-1e6, low - 1e-3),
                NON_FINITE,
                st.booleans(),
                JUNK_TEXT.filter(lambda s: not _parses_as_number(s)),
            ),
        )
    if rule.kind == "bool":
        return _kind(
            st.booleans(), st.one_of(st.integers(0, 1), st.sampled_from(["true", "yes"]), st.none())
        )
    if rule.kind == "choice":
        return _choice(*rule.choices)
    positive = _real(1e-9, 1.0)
    if rule.kind == "schedule":
        return _kind(
            st.one_of(positive, positive.map(lambda x: f"lin_{x}")),
            st.one_of(_real(-1.0, 0.0), NON_FINITE, HUGE_INT, st.sampled_from(["lin_", "lin", "lin_-1", "lin_0", "lin_nan", "lin_inf", "exp_0.1", "lin_abc"]), st.booleans(), st.none()),
        )  # fmt: skip
    if rule.kind == "float_or_auto":
        return _kind(
            st.one_of(_real(-1e3, 1e3), st.just("auto"), positive.map(lambda x: f"auto_{x}")),
            st.one_of(NON_FINITE, HUGE_INT, st.sampled_from(["auto_nan", "auto_inf", "automatic", "auto_x", "manual"]), st.booleans(), st.none()),
        )  # fmt: skip
    if rule.kind == "weights":
        names = st.text(alphabet="abcdefghij_", min_size=1, max_size=8)
        bad = st.one_of(_real(-1e3, 0.0), NON_FINITE, st.booleans(), st.none(), st.just([1.0]))
        return _kind(
            st.dictionaries(names, _real(1e-6, 1e3), min_size=1, max_size=4),
            st.one_of(st.just({}), st.dictionaries(names, bad, min_size=1, max_size=3), JUNK_TEXT, st.integers(), st.lists(names, min_size=1)),
        )  # fmt: skip
    if rule.kind == "choice_per_name":
        one = _choice(*rule.choices)
        names = st.text(alphabet="abcdefghij_", min_size=1, max_size=8)
        return _kind(
            st.one_of(one["valid"], st.dictionaries(names, one["valid"], min_size=1, max_size=4)),
            st.one_of(one["invalid"], st.just({}), st.dictionaries(names, one["invalid"], min_size=1, max_size=3)),
        )  # fmt: skip
    raise AssertionError(f"no fuzz values for rule kind {rule.kind!r}")


LAYERS = st.lists(st.integers(1, 512), min_size=1, max_size=3)


def _net_arch(heads: tuple[str, ...]) -> dict[str, Any]:
    """Valid and invalid ``net_arch`` values for a policy whose heads are ``heads``."""
    return _kind(
    st.one_of(LAYERS, st.dictionaries(st.sampled_from(heads), LAYERS, min_size=1)),
    st.one_of(st.lists(st.one_of(st.integers(-5, 0), st.booleans(), JUNK_TEXT), min_size=1, max_size=3), st.just({}), st.dictionaries(st.sampled_from(["actor", "x"]), LAYERS, min_size=1), JUNK_TEXT, st.integers()),
    )  # fmt: skip


def _algo_spec(algo: str) -> dict[str, Any]:
    spec = {
        k: _rule_values(r)
        for k, r in {**TRAINING_KEYS, **ALGO_KEYS[algo]}.items()
        if r.kind != "mapping"
    }
    sub = {
        k: _net_arch(r.choices) if k == "net_arch" else _rule_values(r)
        for k, r in POLICY_KWARGS[algo].items()
    }
    return spec | {f"policy_kwargs.{k}": v for k, v in sub.items()}  # fmt: skip


ALGO_SPECS = {algo: _algo_spec(algo) for algo in ALGORITHMS}


def _put(data: dict[str, Any], key: str, value: Any) -> None:
    if key.startswith("policy_kwargs."):
        data.setdefault("policy_kwargs", {})[key.split(".", 1)[1]] = value
    else:
        data[key] = value


@st.composite
def hyperparameters(draw: st.DrawFn) -> tuple[str, dict[str, Any], set[str]]:
    """An algorithm, a hyper-parameter mapping for it, and the keys made invalid."""
    algo = draw(st.sampled_from(ALGORITHMS))
    spec = ALGO_SPECS[algo]
    data: dict[str, Any] = {}
    keys = [
        "n_envs",
        "total_timesteps",
        *draw(st.lists(st.sampled_from(sorted(spec)), unique=True, max_size=8)),
    ]
    for key in keys:
        _put(data, key, draw(spec[key]["valid"]))
    bad: set[str] = set()
    for _ in range(draw(st.integers(0, 2))):
        how = draw(
            st.sampled_from(
                ["value", "value", "value", "missing", "unknown", "unknown_sub", "other_algo"]
            )
        )
        if how == "unknown_sub" and isinstance(data.get("policy_kwargs", {}), dict):
            sub = draw(UNKNOWN_KEYS.filter(lambda k: k not in POLICY_KWARGS[algo]))
            data.setdefault("policy_kwargs", {})[sub] = 1
            key = f"policy_kwargs.{sub}"
        elif how == "unknown_sub":
            continue
        elif how == "missing":
            key = draw(st.sampled_from(["n_envs", "total_timesteps"]))
            data.pop(key, None)
        elif how == "unknown":
            key = draw(UNKNOWN_KEYS.filter(lambda k: k not in spec and k != "policy_kwargs"))
            data[key] = draw(JUNK_TEXT)
        elif how == "other_algo":  # a key of another algorithm: valid there, unknown here
            others = {k for a in ALGORITHMS for k in ALGO_SPECS[a]} - set(spec)
            key = draw(st.sampled_from(sorted(others)))
            data[key] = 1
        else:
            key = draw(st.sampled_from(sorted(spec)))
            nested = key.startswith("policy_kwargs.")
            if nested and not isinstance(data.get("policy_kwargs", {}), dict):
                continue  # the whole mapping is already broken
            if nested and draw(st.booleans()):  # break the whole mapping instead
                data["policy_kwargs"] = draw(NOT_A_MAPPING)
                key = "policy_kwargs"
            else:
                _put(data, key, draw(spec[key]["invalid"]))
        bad.add(key)
    if "policy_kwargs" in bad:
        bad = {k for k in bad if not str(k).startswith("policy_kwargs.")}
    kwargs = data.get("policy_kwargs")
    features = kwargs.get("features_extractor", "flatten") if isinstance(kwargs, dict) else None
    dict_features = ("combined", "keypoints", "marker_keypoints")
    if (
        not bad
        and data.get("normalize") is True
        and features not in (None, "flatten", *dict_features)
    ):
        bad.add("policy_kwargs.features_extractor")  # reads the raw observation
    dict_policy = data.get("policy", "MlpPolicy") == "MultiInputPolicy"
    named = isinstance(kwargs, dict) and "features_extractor" in kwargs
    if not bad and named and dict_policy != (features in dict_features):
        bad.add("policy_kwargs.features_extractor")  # reads another observation than the policy
    if not bad and features == "marker_keypoints" and data.get("ee_crop"):
        bad.add("policy_kwargs.features_extractor")  # reads the wide image alone
    for key in IMITATION_DEFAULTS:  # checked first: an imitation setting needs imitate
        if not bad and key in data and "imitate" not in data:
            bad.add(key)
    curricula = ("curriculum_tolerance", "curriculum_hold")
    for key in ("curriculum_steps", "curriculum_delay"):
        if not bad and key in data and not any(k in data for k in curricula):
            bad.add(key)  # a curriculum needs its starting value
    if not bad and "front_end_stack" in data and "front_end" not in data:
        bad.add("front_end_stack")  # the front end's stack needs the front end
    return algo, data, bad


def _same_number(got: Any, want: Any) -> bool:
    if isinstance(want, str) and _parses_as_number(want):
        want = float(want)
    return got == want or (isinstance(got, float) and got == float(want))


@settings(FUZZ, max_examples=150)
@given(case=hyperparameters())
@example(case=("ppo", {"n_envs": 2**1024, "total_timesteps": 1}, {"n_envs"}))
@example(
    case=("ppo", {"n_envs": 1, "total_timesteps": 1, "front_end_stack": 1}, {"front_end_stack"})
)
@example(
    case=("ppo", {"n_envs": 1, "total_timesteps": 1, "learning_rate": "lin_nan"}, {"learning_rate"})
)
@example(case=("sac", {"n_envs": 1, "total_timesteps": 1, "ent_coef": "auto_inf"}, {"ent_coef"}))
@example(
    case=(
        "tqc",
        {"n_envs": 1, "total_timesteps": 1, "normalize": True,
         "policy_kwargs": {"features_extractor": "relative_log_distance"}},
        {"policy_kwargs.features_extractor"},
    )
)  # fmt: skip
@example(
    case=(
        "ppo",
        {"n_envs": 1, "total_timesteps": 1, "policy_kwargs": {"net_arch": [True]}},
        {"policy_kwargs.net_arch"},
    )
)
def test_algorithm_yaml_loads_as_written_or_is_a_config_error_naming_the_file_and_key(
    tmp_path, case
):
    algo, data, bad = case
    path = _write(tmp_path, "fuzz_algo.yaml", _dump(data))
    if not bad:
        hp, source = load_hyperparameters(algo, path)
        assert source == path
        for key, value in data.items():
            if key == "policy_kwargs":
                assert hp[key] == value
            else:
                assert _same_number(hp[key], value), (key, hp[key], value)
        return
    with pytest.raises(ConfigError) as raised:
        load_hyperparameters(algo, path)
    message = str(raised.value)
    assert str(path) in message and "\n" not in message
    assert _names_one_of(message, bad), (message, bad)


@settings(FUZZ, max_examples=40)
@given(
    algo=st.sampled_from(ALGORITHMS),
    text=st.one_of(st.sampled_from(HOSTILE_YAML), st.text(max_size=120), NOT_A_MAPPING.map(_dump)),
)
def test_any_text_as_an_algorithm_file_loads_or_is_a_config_error(tmp_path, algo, text):
    path = _write(tmp_path, "fuzz_algo_text.yaml", text)
    try:
        load_hyperparameters(algo, path)
    except ConfigError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)
