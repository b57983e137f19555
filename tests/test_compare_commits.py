"""``benchmarks/compare_commits.py``: the figures it reads from the benchmarks' own output, and
what it calls worse."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).parents[1] / "benchmarks"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def compare():
    return _load("compare_commits")


def test_the_figures_of_bench_env_and_bench_reset_are_read_by_their_headers(compare, capsys):
    env = ["--scenarios", "paper", "noisy", "--sources", "truth", "--steps", "20"]
    assert _load("bench_env").main(env) == 0
    figures = compare.BENCHMARKS["env-single"].figures(capsys.readouterr().out)
    assert list(figures) == ["paper truth steps/s", "noisy truth steps/s"]
    assert all(value > 0 for value in figures.values())
    reset = ["--modes", "single", "vector", "--episodes", "2", "--num-envs", "2", "--repeats", "1"]
    assert _load("bench_reset").main(reset) == 0
    figures = compare.BENCHMARKS["reset"].figures(capsys.readouterr().out)
    assert list(figures) == ["single total", "vector/2 total"]  # the vector row has no bound


def test_a_table_of_other_rows_or_none_is_said(compare):
    table = compare.Table("us/env/update", lower_is_better=True)
    out = (
        "operation                    us/env/update  env-updates/s\n"
        "---------------------------  -------------  -------------\n"
        "update, n = 1, per env               165.8           6031\n"
        "\n"
        "a note after the table 1 2\n"
    )
    assert table(out) == {"update, n = 1, per env us/env/update": 165.8}
    with pytest.raises(ValueError, match="no header with a 'steps/s' column"):
        compare.Table("steps/s")(out)


def test_worse_is_a_loss_beyond_bases_own_spread(compare):
    faster = compare.Table("steps/s")
    base = [{"a steps/s": 100.0, "gone steps/s": 1.0}, {"a steps/s": 110.0, "gone steps/s": 1.0}]
    within = compare.compare("env", faster, base, [{"a steps/s": 96.0}] * 2)
    assert within[0][-1] == "higher is better" and within[0][4] == "0.914"
    assert within[1][1:] == ["gone steps/s", "-", "-", "-", "-", "only in BASE"]
    beyond = compare.compare("env", faster, base, [{"a steps/s": 90.0}] * 2)
    assert beyond[0][-1] == "higher is better; worse"
    timed = compare.compare("run", None, [{"wall s": 2.0}] * 2, [{"wall s": 2.5}] * 2)
    assert timed[0][-1] == "lower is better; worse"


def test_a_benchmark_is_a_name_or_a_labelled_command(compare):
    label, words, figures = compare.parse_bench("reset", seconds=1, episodes=7)
    assert label == "reset" and words[0] == sys.executable and words[-3:] == ["7", "--repeats", "1"]
    label, words, figures = compare.parse_bench("quick=python evaluate.py --suite quick", 1, 1)
    assert (label, words[1:], figures) == ("quick", ["evaluate.py", "--suite", "quick"], None)
    with pytest.raises(ValueError, match="not one of env-single"):
        compare.parse_bench("nonsense", 1, 1)
