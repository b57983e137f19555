"""Fuzzing what users hand the benchmark at run time (issue 10, item 7): actions and command lines.

Actions of every shape, dtype and value (NaN, infinities, huge numbers, lists, scalars, objects)
go to ``CaptureEnv.step`` and to the batched vector env: a real-number array of the right shape
with finite entries steps (out-of-range values are clipped), anything else raises the documented
``ValueError`` of `capture_bench.engine.task.check_actions`, nothing else. Generated command lines
(real options with good and bad values, unknown options, junk, huge and negative numbers) go to
``evaluate.main`` and ``train.main`` with the stage that does the work replaced by a stand-in: the
exit status is 0 or 2, stderr holds at most one ``prog: error: ...`` line and never a traceback,
a valid command line reaches the stand-in, and nothing is written outside ``tmp_path``.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import shutil
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import evaluate
import train
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.evaluation import cli as evaluation_cli
from capture_bench.evaluation.reporting.report import ReportData
from capture_bench.evaluation.running.backends import BACKENDS
from capture_bench.task.scenarios import CONFIG_DIR, list_scenarios
from capture_bench.training.common import run as training_run
from capture_bench.training.config.hyperparameters import ALGORITHMS

FUZZ = settings(
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
REPO = Path(__file__).resolve().parents[1]

# -- actions -----------------------------------------------------------------------------------
REAL_DTYPES = [np.bool_, np.int8, np.int32, np.int64, np.uint8, np.uint64]
REAL_DTYPES += [np.float16, np.float32, np.float64, np.longdouble]
OTHER_DTYPES = [np.complex64, np.dtype("U3"), np.dtype("S3"), np.dtype("M8[s]"), np.dtype(object)]


def _expected_ok(action: Any, shape: tuple[int, ...]) -> bool:
    """The documented action rule: real numbers (bool, int or float dtype, or a list of Python
    numbers), exactly ``shape``, every entry finite once read as float64."""
    if isinstance(action, np.ndarray):
        if action.dtype.kind not in "biuf" or action.shape != shape:
            return False
        with np.errstate(over="ignore"):
            return bool(np.isfinite(action.astype(np.float64)).all())
    flat, dims = [], []

    def walk(item: Any, depth: int) -> bool:
        if isinstance(item, (list, tuple)):
            if len(dims) <= depth:
                dims.append(len(item))
            return dims[depth] == len(item) and all(walk(x, depth + 1) for x in item)
        flat.append(item)
        return depth == len(shape)

    if not walk(action, 0) or tuple(dims) != shape:
        return False
    return all(
        isinstance(x, float) and math.isfinite(x) or isinstance(x, int) and abs(x) < 2**63
        for x in flat  # bool is an int; ints beyond int64 make numpy build an object array
    )


def _numbers(finite_only: bool) -> st.SearchStrategy:
    floats = st.floats(allow_nan=not finite_only, allow_infinity=not finite_only)
    return st.one_of(st.integers(-(2**63) + 1, 2**63 - 1), floats, st.booleans())


def actions(shape: tuple[int, ...]) -> st.SearchStrategy:
    """Anything a policy might return for an action of ``shape``, valid or not."""
    right = st.just(shape)
    wrong = hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5).filter(
        lambda s: s != shape
    )
    arrays = hnp.arrays(st.sampled_from(REAL_DTYPES), st.one_of(right, right, wrong))
    huge = st.sampled_from([1e300, -1e308, np.finfo(np.float64).max, 65504.0, 1e5, 2**62])
    lists = st.recursive(
        _numbers(finite_only=False) | st.none() | st.text(max_size=2),
        lambda inner: st.lists(inner, max_size=5) | st.tuples(inner, inner, inner),
        max_leaves=20,
    )
    rows = st.lists(_numbers(finite_only=True), min_size=shape[-1], max_size=shape[-1])
    nested = rows if len(shape) == 1 else st.lists(rows, min_size=shape[0], max_size=shape[0])
    return st.one_of(
        arrays,
        hnp.arrays(st.sampled_from(OTHER_DTYPES), right),
        hnp.arrays(np.float64, right, elements=huge),
        nested,  # lists of Python numbers of the right shape: valid
        nested.map(tuple),
        lists,
        st.one_of(_numbers(finite_only=False), st.none(), st.text(max_size=4), st.just({})),
        st.lists(st.integers(2**64, 2**80), min_size=shape[-1], max_size=shape[-1]),
    )


@pytest.fixture(scope="module")
def single_env():
    env = CaptureEnv("paper")
    env.reset(seed=0)
    yield env
    env.close()


@pytest.fixture(scope="module")
def vector_env():
    envs = gym.make_vec("CaptureBench/Paper-v1", num_envs=4)
    envs.reset(seed=0)
    yield envs
    envs.close()


def _step_or_refuse(env: Any, action: Any, shape: tuple[int, ...]) -> None:
    expected = _expected_ok(action, shape)
    try:
        obs, reward, terminated, truncated, info = env.step(action)
    except ValueError as exc:
        assert not expected, f"a valid action was refused: {exc}"
        assert "action" in str(exc)
        event("refused")
        return
    assert expected, f"an invalid action was taken: {action!r}"
    event("stepped")
    batch = shape[:-1]
    assert obs.shape == (*batch, 16) and obs.dtype == np.float32 and np.isfinite(obs).all()
    assert np.shape(reward) == batch and np.isfinite(reward).all()
    assert np.shape(terminated) == batch and np.shape(truncated) == batch
    assert isinstance(info, dict)
    if not batch and (terminated or truncated):  # the vector env resets itself
        env.reset(seed=int(info["time"] * 1000))


@pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")
@settings(FUZZ, max_examples=150)
@given(action=actions((3,)))
@example(action=np.array([np.nan, 0.0, 0.0]))
@example(action=np.array([1e300, -1e300, 0.0]))
@example(action=[2**64, 0, 0])
@example(action=np.array([1, 2, 3], dtype=object))
def test_capture_env_steps_a_valid_action_and_refuses_any_other_with_value_error(
    single_env, action
):
    _step_or_refuse(single_env, action, (3,))


@pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")
@settings(FUZZ, max_examples=100)
@given(actions=actions((4, 3)))
@example(actions=np.zeros((3,)))
@example(actions=np.zeros((1, 3)))
@example(actions=np.full((4, 3), np.inf, dtype=np.float16))
@example(actions=[[0, 0, 0], [0, 0, 0], [0, math.nan, 0], [0, 0, 0]])
def test_vector_env_steps_valid_actions_and_refuses_any_other_with_value_error(vector_env, actions):
    _step_or_refuse(vector_env, actions, (4, 3))


# -- command lines -----------------------------------------------------------------------------
TMP = "{tmp}"  # replaced by the test's folder of input files
JUNK = st.one_of(
    st.text(st.characters(exclude_categories=("Cs", "Cc")), max_size=12),
    st.integers(250, 400).map(lambda n: "x" * n),  # longer than a file name may be
    st.integers(250, 400).map(lambda n: "x" * n + ".yaml"),
    st.sampled_from(["-", "--", "-1", "=", "--=", "~", "/", ".", "..", "*", "all", "None", "nan"]),
)
NUMBERS = st.one_of(
    st.integers(-3, 300).map(str),
    st.integers(-(10**30), 10**30).map(str),
    st.sampled_from(["1.5", "1e3", "0x10", "inf", "-0", " 4", "1_000", "٣"]),
    JUNK,
)
PATHS = st.sampled_from(
    [f"{TMP}/fresh", f"{TMP}/a_file", f"{TMP}/empty_dir", "/proc/fuzz", "/dev/null/x"]
)


def _option(
    name: str, valid: st.SearchStrategy[str] | None, invalid: st.SearchStrategy[str]
) -> Any:
    """An option and its values: ``(name, valid values or None, any values)``."""
    return name, valid, invalid if valid is None else st.one_of(valid, invalid)


def _given(name: str, values: st.SearchStrategy[str]) -> st.SearchStrategy[list[str]]:
    """``[name, value]``, ``[name=value]``, or the option alone (its value missing)."""
    if name in FLAGS:
        return st.just([name])
    if name in MANY_VALUES:
        return st.lists(values, min_size=1, max_size=3).map(lambda v: [name, *v])
    return st.one_of(
        st.tuples(st.just(name), values).map(list),
        values.map(lambda v: [f"{name}={v}"]),
        st.just([name]),
    )


def _command_lines(options: list[Any]) -> st.SearchStrategy[list[str]]:
    """Half the time a few real options with valid values, half the time anything: real options
    with any value or none, flags, unknown options and junk, in any order."""
    usable = [o for o in options if o[1] is not None]
    valid = st.lists(st.sampled_from(usable), unique_by=lambda o: o[0], max_size=4).flatmap(
        lambda chosen: st.tuples(*[st.tuples(st.just(n), v).map(list) for n, v, _ in chosen])
    )
    extra = st.one_of(
        JUNK.map(lambda s: [s]),
        st.sampled_from([["--help"], ["-h"], ["--bogus"], ["--bogus", "1"], ["-x"]]),
    )
    anything = [_given(name, values) for name, _, values in options]
    fuzzed = st.lists(st.one_of(*anything, *anything, extra), max_size=5)
    return st.one_of(valid, fuzzed).map(
        lambda chunks: [a for a in itertools.chain(*chunks) if a != FLAG_VALUE]
    )


def _names(valid: st.SearchStrategy[str]) -> st.SearchStrategy[str]:
    """One name, or a comma-separated list of names."""
    return st.one_of(valid, st.lists(valid, min_size=2, max_size=3).map(",".join))


MANY_VALUES = ("--agents", "--scenarios")  # nargs="+"
FLAGS = ("--trust-model",)  # options that take no value
FLAG_VALUE = "<no value>"
SCENARIO_NAMES = st.sampled_from([*list_scenarios(), f"{TMP}/paper_copy.yaml"])
BAD_SCENARIOS = st.sampled_from([f"{TMP}/broken.yaml", f"{TMP}/none.yaml", "all"]) | JUNK
AGENT_NAMES = st.sampled_from(["hold", "random", "incremental_ik", "oracle"])
BAD_AGENTS = st.sampled_from(["no_such_module:Agent", "math:pi", "models/none"]) | JUNK
POSITIVE = st.integers(1, 100).map(str)
EVALUATE_OPTIONS = [
    _option("--suite", st.sampled_from(["quick", "default", f"{TMP}/suite.yaml"]), st.sampled_from([f"{TMP}/broken.yaml", f"{TMP}/none.yml"]) | JUNK),
    _option("--agents", _names(AGENT_NAMES), _names(AGENT_NAMES | BAD_AGENTS)),
    _option("--scenarios", _names(SCENARIO_NAMES), _names(SCENARIO_NAMES | BAD_SCENARIOS)),
    _option("--episodes", POSITIVE, NUMBERS),
    _option("--workers", POSITIVE, NUMBERS),
    _option("--backend", st.sampled_from(BACKENDS), JUNK),
    _option("--ray-address", JUNK, JUNK),
    _option("--out", st.just(f"{TMP}/fresh"), PATHS),
    _option("--episode-plots", st.just(f"{TMP}/fresh"), PATHS),
    _option("--trust-model", st.just(FLAG_VALUE), st.just(FLAG_VALUE)),
]  # fmt: skip
TRAIN_OPTIONS = [
    _option("--algo", st.sampled_from([*ALGORITHMS, "PPO"]), st.just("dqn") | JUNK),
    _option("--set", st.sampled_from(["gamma=0.9", "policy_kwargs.net_arch=[8]", "learning_rate=lin_1e-3", "n_envs=2"]), st.sampled_from(["gamma", "=", "gamma=", "gamma=[", "gama=1", "a.b=1", "n_critics=2"]) | JUNK),
    _option("--reward", st.sampled_from(["dense", "sparse"]), JUNK),
    _option("--scenario", SCENARIO_NAMES, BAD_SCENARIOS),
    _option("--config", st.just(f"{TMP}/ppo.yaml"), st.sampled_from([str(CONFIG_DIR / "algos" / "sac.yaml"), f"{TMP}/broken.yaml", f"{TMP}/empty_dir", f"{TMP}/none.yaml"]) | JUNK),
    _option("--total-timesteps", st.integers(1, 10**7).map(str), NUMBERS),
    _option("--n-envs", st.integers(1, 16).map(str), st.just("100000") | NUMBERS),
    _option("--vec-env", st.sampled_from(["batched", "dummy", "subproc"]), JUNK),
    _option("--seed", st.integers(0, 999).map(str), st.sampled_from(["1000000", "-1"]) | NUMBERS),
    _option("--observation-source", st.sampled_from(["ekf", "photogrammetry", "truth"]), JUNK),
    _option("--run-dir", st.just(f"{TMP}/fresh"), PATHS),
    _option("--resume", None, st.sampled_from([f"{TMP}/fresh", f"{TMP}/empty_dir", f"{TMP}/bad_run", f"{TMP}/a_file"]) | JUNK),
    _option("--device", st.sampled_from(["cpu", "auto"]), st.just("cuda") | JUNK),
]  # fmt: skip


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """Input files the command lines name: copies of shipped configs, broken ones, a plain file,
    an empty folder, a run folder whose config.json is not JSON."""
    root = tmp_path_factory.mktemp("fuzz_inputs")
    shutil.copy(CONFIG_DIR / "suites" / "quick.yaml", root / "suite.yaml")
    shutil.copy(CONFIG_DIR / "scenarios" / "paper.yaml", root / "paper_copy.yaml")
    (root / "ppo.yaml").write_text(
        (CONFIG_DIR / "algos" / "ppo.yaml").read_text().replace("3000000", "4096")
    )
    (root / "broken.yaml").write_text("episodes: [1\nn_envs: {")
    (root / "a_file").write_text("not a folder")
    (root / "empty_dir").mkdir()
    (root / "bad_run").mkdir()
    (root / "bad_run" / "config.json").write_text("{not json")
    return root


def _snapshot() -> list[tuple[str, int, int]]:
    """What the repository holds where a command could write (reports, runs, models, configs,
    the root listing): path, size and modification time of every file."""
    found = [(p.name, 0, 0) for p in REPO.iterdir()]
    for top in ("reports", "runs", "models", "configs"):
        for folder, _, files in os.walk(REPO / top):
            for name in files:
                stat = os.stat(os.path.join(folder, name))
                found.append((os.path.join(folder, name), stat.st_size, stat.st_mtime_ns))
    return sorted(found)


@pytest.fixture
def repository_untouched():
    before = _snapshot()
    yield
    assert _snapshot() == before, "a command wrote into the repository"


def _check_streams(prog: str, status: int, err: str, allowed: str) -> None:
    """Exit status 0 or 2; stderr: no traceback, one error line exactly when the status is 2,
    every other line a note (or evaluate.py's progress bar)."""
    assert status in (0, 2), (status, err)
    assert "Traceback" not in err, err
    lines = err.splitlines()
    errors = [line for line in lines if line.startswith(f"{prog}: error: ")]
    assert len(errors) == (1 if status == 2 else 0), err
    others = [line for line in lines if line not in errors and line.strip()]
    assert all(re.match(allowed, line) for line in others), err


def _run_main(main: Any, argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # allowed, if argparse's own: 0 (--help) or 2 (bad option)
        return 0 if exc.code is None else exc.code if isinstance(exc.code, int) else 1


def _under(path: Any, root: Path) -> bool:
    return Path(path).resolve().is_relative_to(root.resolve())


_fresh = itertools.count()


@settings(FUZZ, max_examples=120)
@given(argv=_command_lines(EVALUATE_OPTIONS), out=PATHS)
@example(argv=["--suite", "quick"], out=f"{TMP}/fresh")
@example(argv=["--agents", "hold", "--scenarios", "x" * 300], out=f"{TMP}/fresh")
@example(argv=["--suite", "x" * 300 + ".yaml", "--agents", "hold"], out=f"{TMP}/fresh")
def test_evaluate_command_line_exits_0_or_2_with_one_error_line_and_writes_nothing_outside_tmp(
    monkeypatch, capsys, tmp_path, inputs, repository_untouched, argv, out
):
    cwd = tmp_path / "cwd"  # relative defaults (reports/) land here
    cwd.mkdir(exist_ok=True)
    monkeypatch.chdir(cwd)
    calls = []

    def run_evaluation(plan, config, command, progress=None):
        for folder in (config.out, config.episode_plots or tmp_path):
            assert _under(folder, tmp_path) or _under(folder, inputs), folder
        calls.append(plan)
        progress(len(plan.tasks))
        data = ReportData(plan.suite.name, "", command, plan.suite.reference, [], [], [], {})
        return data, config.out / plan.suite.name

    monkeypatch.setattr(evaluation_cli, "run_evaluation", run_evaluation)
    fresh = f"{inputs}/fresh{next(_fresh)}"  # a folder of its own for each command line
    argv = [a.replace(f"{TMP}/fresh", fresh).replace(TMP, str(inputs)) for a in argv]
    if not any(a.startswith("--ag") for a in argv):  # the default suite's models/* load torch
        argv += ["--agents", "hold"]
    out = out.replace(f"{TMP}/fresh", fresh).replace(TMP, str(inputs))
    capsys.readouterr()
    status = _run_main(evaluate.main, [*argv, "--out", out])
    stdout, err = capsys.readouterr()
    _check_streams("evaluate.py", status, err, r"evaluate\.py: note: |\S+: episodes ")
    event("reached the stand-in" if calls else f"exit {status} before any work")
    if status == 0:
        assert calls or "usage:" in stdout, (argv, stdout)
    else:
        assert not calls


@settings(FUZZ, max_examples=120)
@given(argv=_command_lines(TRAIN_OPTIONS))
@example(argv=["--scenario", "paper", "--config", f"{TMP}/ppo.yaml"])
@example(argv=["--scenario", "x" * 300])
@example(argv=["--config", "x" * 300 + ".yaml"])
@example(argv=["--resume", "x" * 300])
def test_train_command_line_exits_0_or_2_with_one_error_line_and_writes_nothing_outside_tmp(
    monkeypatch, capsys, tmp_path, inputs, repository_untouched, argv
):
    cwd = tmp_path / "cwd"  # relative defaults (runs/) land here
    cwd.mkdir(exist_ok=True)
    monkeypatch.chdir(cwd)
    calls = []

    def fake_train(config, hp, run_dir, checkpoint):
        assert _under(run_dir, tmp_path) or _under(run_dir, inputs)
        calls.append(config)
        return 0

    monkeypatch.setattr(training_run, "train", fake_train)
    fresh = f"{inputs}/fresh{next(_fresh)}"  # a folder of its own for each command line
    argv = [a.replace(f"{TMP}/fresh", fresh).replace(TMP, str(inputs)) for a in argv]
    if not any(a.startswith(("--res", "--run")) for a in argv):  # a new folder per valid run
        argv += ["--run-dir", str(tmp_path / f"run{next(_fresh)}")]
    capsys.readouterr()
    status = _run_main(train.main, argv)
    stdout, err = capsys.readouterr()
    _check_streams("train.py", status, err, r"$^")
    event("reached the stand-in" if calls else f"exit {status} before any work")
    if status == 0:
        assert calls or "usage:" in stdout, (argv, stdout)
    else:
        assert not calls
