"""``python -m capture_bench.agents.convert DIR --trust-model`` on bad input: one line on stderr
naming the file, the problem and what would be right, exit status 2, and nothing written."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from stand_in import sb3_model

from capture_bench.agents.convert import main
from capture_bench.agents.policy_file import save_policy

ROOT = Path(__file__).resolve().parents[1]
PREFIX = "python -m capture_bench.agents.convert: error: "


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """An SB3 ``model.zip`` and the safe form (``policy.pt`` + ``metadata.json``) of a small PPO
    model, to copy into the directories the tests break."""
    root = tmp_path_factory.mktemp("made")
    model, _ = sb3_model("PPO")
    model.save(root / "model.zip")
    save_policy(root / "safe", "PPO", model.policy)
    return root


def _zip(d: Path, made: Path) -> None:
    shutil.copy(made / "model.zip", d / "model.zip")


def _metadata(d: Path, entries: object) -> None:
    (d / "metadata.json").write_text(json.dumps(entries))


def _declared(d: Path, made: Path) -> None:
    shutil.copy(made / "safe" / "metadata.json", d / "metadata.json")


def only_model_zip(d, made):
    _zip(d, made)
    return d


def metadata_without_policy_pt(d, made):
    _metadata(d, {"algorithm": "PPO"})
    return d


def declared_metadata_without_policy_pt_beside_the_zip(d, made):
    _declared(d, made)
    _zip(d, made)
    return d


def non_json_metadata(d, made):
    (d / "metadata.json").write_text("algorithm: PPO\n")
    _zip(d, made)
    return d


def metadata_not_a_mapping(d, made):
    _metadata(d, ["PPO"])
    _zip(d, made)
    return d


def corrupt_policy_pt(d, made):
    _declared(d, made)
    (d / "policy.pt").write_bytes(b"\x80\x02 not a torch file")
    return d


def empty_directory(d, made):
    return d


def a_file_instead_of_a_directory(d, made):
    _zip(d, made)
    return d / "model.zip"


def a_model_zip_that_is_not_a_zip(d, made):
    _metadata(d, {"algorithm": "PPO"})
    (d / "model.zip").write_text("not a zip")
    return d


def a_run_without_best(d, made):
    _declared(d, made)
    shutil.copy(made / "safe" / "policy.pt", d / "policy.pt")
    return d / "best"


def an_unknown_algorithm(d, made):
    _metadata(d, {"algorithm": "DQN"})
    _zip(d, made)
    return d


def a_yaml_date_json_cannot_hold(d, made):
    (d / "metadata.yaml").write_text("algorithm: PPO\ntrained: 2024-05-01\n")
    _zip(d, made)
    return d


# (how to break a directory d, what the message says; "{d}" is d)
CASES = [
    (only_model_zip, ["{d}: no metadata file", "found: model.zip", '{"algorithm": "PPO"}']),
    (
        metadata_without_policy_pt,
        ["{d}: no SB3 .zip to convert (found: metadata.json)", "model.save"],
    ),
    (
        declared_metadata_without_policy_pt_beside_the_zip,
        ["{d}/policy.pt: missing, though metadata.json declares it", "restore it"],
    ),
    (non_json_metadata, ["{d}/metadata.json: not valid JSON", '{"algorithm": "PPO"}']),
    (metadata_not_a_mapping, ["{d}/metadata.json: holds a list", '{"algorithm": "PPO"}']),
    (corrupt_policy_pt, ["{d}: no SB3 .zip to convert", "found: metadata.json, policy.pt"]),
    (empty_directory, ["{d}: no metadata file (found: nothing)", '{"algorithm": "PPO"}']),
    (
        a_file_instead_of_a_directory,
        ["{d}/model.zip: a file, not a directory", "may be {d}", "SB3 .zip"],
    ),
    (a_model_zip_that_is_not_a_zip, ["{d}/model.zip: not a loadable PPO model", "zip"]),
    (a_run_without_best, ["{d}/best: no such directory", "eval_freq > 0", "final model is {d}"]),
    (an_unknown_algorithm, ["{d}/metadata.json: key 'algorithm' is 'DQN'", "valid: PPO"]),
    (a_yaml_date_json_cannot_hold, ["{d}/metadata.yaml: entry 'trained'", "quote a date"]),
]


def _files(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir()}


@pytest.mark.parametrize(("build", "expected"), CASES, ids=[b.__name__ for b, _ in CASES])
def test_a_bad_model_directory_is_one_line_and_exit_2_and_writes_nothing(
    build, expected, made, tmp_path, capsys
):
    d = tmp_path / "m"
    d.mkdir()
    target = build(d, made)
    before = _files(d)
    assert main([str(target), "--trust-model"]) == 2
    captured = capsys.readouterr()
    err = captured.err
    assert captured.out == ""
    assert err.startswith(PREFIX) and err.count("\n") == 1 and "Traceback" not in err
    for fragment in expected:
        assert fragment.replace("{d}", str(d)) in err
    assert _files(d) == before  # nothing written, not even a temporary file


def test_the_readme_placeholder_path_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys):
    placeholder = re.search(
        r"python -m capture_bench\.agents\.convert (\S+) --trust-model",
        (ROOT / "README.md").read_text(),
    )
    assert placeholder is not None
    monkeypatch.chdir(tmp_path)
    assert main([placeholder.group(1), "--trust-model"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"{placeholder.group(1)}: no such directory; convert takes a directory holding" in err


@pytest.mark.parametrize("metadata", [None, {"algorithm": "DQN"}], ids=["readme_path", "dqn"])
def test_run_as_a_module_a_bad_directory_is_one_line_without_a_traceback(metadata, tmp_path):
    if metadata is None:  # README's placeholder path: no such directory
        target = "path/to/sb3_model_dir"
    else:  # an error raised in capture_bench.agents.sb3_policy, under the module run as __main__
        (tmp_path / "m").mkdir()
        _metadata(tmp_path / "m", metadata)
        (tmp_path / "m" / "model.zip").write_bytes(b"never read")
        target = "m"
    result = subprocess.run(
        [sys.executable, "-m", "capture_bench.agents.convert", target, "--trust-model"],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},  # this checkout, wherever it is installed
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.startswith(PREFIX) and result.stderr.count("\n") == 1
    assert "Traceback" not in result.stderr and target in result.stderr


def test_one_bad_directory_among_several_writes_none_of_them(made, tmp_path, capsys):
    good, bad = tmp_path / "good", tmp_path / "bad"
    for d in (good, bad):
        d.mkdir()
        _zip(d, made)
    _metadata(good, {"algorithm": "PPO"})
    _metadata(bad, {"algorithm": "SAC"})  # beside a PPO .zip
    assert main([str(good), str(bad), "--trust-model"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "says algorithm SAC, but model.zip holds a PPO" in err
    assert sorted(p.name for p in good.iterdir()) == ["metadata.json", "model.zip"]
    assert main([str(good), "--trust-model"]) == 0
    assert (good / "policy.pt").is_file()
    assert json.loads((good / "metadata.json").read_text())["format"]


@pytest.mark.parametrize("argv", [[], ["--trust-model"]])
def test_missing_arguments_are_one_line_and_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "required" in err
