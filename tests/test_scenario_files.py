"""A bad file under ``configs/scenarios/`` breaks only itself (issue 10, point 3).

Every test runs on a temporary scenario folder holding a copy of the shipped ``paper.yaml`` and two
broken files (a bad value, and bad YAML), with ``SCENARIO_DIR`` pointed at it.
"""

from __future__ import annotations

import importlib
import json
import shutil
from pathlib import Path

import gymnasium as gym
import pytest
from gymnasium.envs.registration import registry

import capture_bench
import evaluate
import train
from capture_bench import __main__ as cli
from capture_bench.evaluation import pipeline
from capture_bench.task import scenarios
from capture_bench.task.scenarios import (
    ConfigError,
    invalid_scenarios,
    list_scenarios,
    load_scenario,
)

SHIPPED = scenarios.SCENARIO_DIR
WARP = "target:\n  motion: warp\n"  # not a motion the benchmark has
WARP_ERROR = "key 'target.motion': 'warp' is not valid; expected one of drift, circular, tumbling"


@pytest.fixture
def scenario_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "scenarios"
    folder.mkdir()
    shutil.copy(SHIPPED / "paper.yaml", folder / "paper.yaml")
    (folder / "warp.yaml").write_text(WARP)
    (folder / "unclosed.yaml").write_text("target: [drift\n")
    monkeypatch.setattr(scenarios, "SCENARIO_DIR", folder)
    monkeypatch.setattr(pipeline, "SCENARIO_DIR", folder)
    before = set(registry)
    yield folder
    for env_id in set(registry) - before:  # what the re-import below registered
        del registry[env_id]


def test_only_valid_files_are_listed_and_each_invalid_one_keeps_its_error(scenario_dir):
    assert list_scenarios() == ["paper"]
    invalid = invalid_scenarios()
    assert sorted(invalid) == ["unclosed", "warp"]
    assert invalid["warp"].startswith(str(scenario_dir / "warp.yaml"))
    assert WARP_ERROR in invalid["warp"]
    assert "invalid YAML" in invalid["unclosed"] and "\n" not in invalid["unclosed"]
    with pytest.raises(ConfigError, match=WARP_ERROR):
        load_scenario("warp")
    with pytest.raises(ConfigError, match=r"unknown scenario 'nope'; valid: paper$"):
        load_scenario("nope")


def test_import_registers_the_valid_scenarios_silently_and_gym_make_reports_a_bad_one(
    scenario_dir, capsys
):
    importlib.reload(capture_bench)  # the import, run again on the folder with broken files
    assert capsys.readouterr() == ("", "")
    assert capture_bench.env_ids() == ["CaptureBench/Paper-v1"]
    assert "CaptureBench/Warp-v1" in registry  # under its file name, so that using it says why
    with pytest.raises(ConfigError, match=WARP_ERROR):
        gym.make("CaptureBench/Warp-v1")
    env = gym.make("CaptureBench/Paper-v1")
    env.close()


def test_evaluate_and_train_name_the_file_and_key_in_one_line(scenario_dir, tmp_path, capsys):
    argv = ["--agents", "hold", "--scenarios", "warp", "--episodes", "1", "--out", str(tmp_path)]
    assert evaluate.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("evaluate.py: error: ") and "\n" not in err and WARP_ERROR in err
    run_dir = tmp_path / "run"
    assert train.main(["--scenario", "warp", "--run-dir", str(run_dir)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("train.py: error: ") and "\n" not in err and WARP_ERROR in err
    assert not run_dir.exists()
    assert list(tmp_path.iterdir()) == [scenario_dir]  # nothing written


def test_a_suite_of_every_scenario_runs_the_valid_ones_and_names_the_skipped_files(
    scenario_dir, tmp_path, capsys
):
    suite = tmp_path / "every.yaml"
    suite.write_text("agents: [hold]\nscenarios: all\nepisodes: 1\nreference: hold\n")
    argv = ["--suite", str(suite), "--backend", "serial", "--out", str(tmp_path / "out")]
    assert evaluate.main(argv) == 0
    err = capsys.readouterr().err.splitlines()
    notes = [line for line in err if "note: skipping" in line]  # (a dirty checkout adds a note)
    assert len(notes) == 2
    assert notes[0].startswith("evaluate.py: note: skipping invalid scenario 'unclosed': ")
    assert notes[1].startswith("evaluate.py: note: skipping invalid scenario 'warp': ")
    assert WARP_ERROR in notes[1]
    results = json.loads((tmp_path / "out" / "every" / "results.json").read_text())
    assert sorted(results["provenance"]["seeds"]) == ["paper"]


def test_list_command_shows_valid_and_invalid_scenarios_suites_and_algorithms(scenario_dir, capsys):
    assert cli.main(["list"]) == 0
    out = capsys.readouterr().out.splitlines()
    paper = next(line for line in out if line.strip().startswith("paper "))
    assert "CaptureBench/Paper-v1" in paper
    assert "evaluation seeds 1000000-1000099 (100)" in paper
    assert "training seeds 0-999999 (1000000)" in paper
    header = out.index("invalid scenario files (skipped; using one raises this error):")
    assert out[header + 1].split()[0] == "unclosed" and "invalid YAML" in out[header + 1]
    assert out[header + 2].split()[0] == "warp" and WARP_ERROR in out[header + 2]
    assert any(line.split()[:2] == ["default", "all;"] for line in out)
    from capture_bench.training.config.hyperparameters import ALGORITHMS

    n = len(ALGORITHMS)
    assert [line.split()[0] for line in out[-n:]] == list(ALGORITHMS)


def test_list_command_help_and_a_bad_command(capsys):
    assert cli.main(["--help"]) == 0
    assert "list" in capsys.readouterr().out
    assert cli.main(["lsit"]) == 2
    assert "invalid choice: 'lsit'" in capsys.readouterr().err
