"""``benchmarks/bench_env.py``: its ``main`` runs, and with ``--panda`` pairs each row with
panda-gym's ``PandaReach-v3`` and prints the ratio (skipped where panda-gym is not installed)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def bench():
    path = Path(__file__).parents[1] / "benchmarks" / "bench_env.py"
    spec = importlib.util.spec_from_file_location("bench_env", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_single_env_rows_and_their_summary(bench, capsys):
    argv = ["--scenarios", "paper", "--sources", "truth", "--steps", "30", "--repeats", "2"]
    assert bench.main(argv) == 0
    out = capsys.readouterr().out
    assert out.count("paper      truth") == 3  # two sweeps and the summary
    assert "median (min-max) of 2 sweeps, 30 steps a row" in out


class FiftyStepEpisodes:
    """Counts the calls ``steps_per_second`` makes; every 50th step truncates."""

    def __init__(self) -> None:
        self.steps = self.resets = 0
        self.closed = False

    def reset(self, seed=None):
        self.resets += 1

    def step(self, action):
        self.steps += 1
        return None, 0.0, False, self.steps % 50 == 0, {}

    def close(self) -> None:
        self.closed = True


def test_a_fixed_number_of_steps(bench):
    env = FiftyStepEpisodes()
    _, episodes = bench.steps_per_second(env, seconds=0.0, steps=620)
    assert (env.steps, episodes, env.resets, env.closed) == (620, 12, 13, True)


def test_panda_reach_is_timed_beside_each_row(bench, capsys):
    pytest.importorskip("panda_gym")
    argv = ["--scenarios", "paper", "--sources", "truth", "--seconds", "0.01", "--panda"]
    assert bench.main(argv) == 0
    header, row = capsys.readouterr().out.splitlines()[1:3]
    assert "PandaReach-v3 steps/s" in header and "ratio" in header
    ours, panda, ratio = (float(row.split()[i]) for i in (2, 5, 6))
    assert ratio == pytest.approx(ours / panda, rel=0.01, abs=0.01)


@pytest.mark.parametrize(
    "argv", [["--panda", "--num-envs", "4"], ["--steps", "10", "--num-envs", "4"], ["--steps", "0"]]
)
def test_refused_combinations(bench, argv):
    with pytest.raises(SystemExit):
        bench.main(argv)
