"""``scripts/plot_ablation.py``: the figure from runs' validations; bad input is one line on
stderr, exit status 2, and no figure."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "plot_ablation.py"
PREFIX = "plot_ablation.py: error: "
HEADER = "step,wall_time_s,capture_rate,median_capture_time,median_ratio_to_limit\n"


@pytest.fixture(scope="module")
def plot():
    spec = importlib.util.spec_from_file_location("plot_ablation", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["plot_ablation"] = module  # where its dataclass looks up its annotations
    try:
        spec.loader.exec_module(module)
        yield module.main
    finally:
        del sys.modules["plot_ablation"]


@pytest.fixture
def run_dir(tmp_path):
    """A train.py run directory with two validations."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "validations.csv").write_text(HEADER + "100,1.0,0.0,nan,nan\n200,2.0,0.5,1.2,3.0\n")
    return run


def test_runs_and_validation_files_make_one_figure(plot, run_dir, tmp_path, capsys):
    csv_file = tmp_path / "copy.csv"
    csv_file.write_text(HEADER + "100,1.0,0.25,1.0,2.0\n")
    out = tmp_path / "figures" / "ablation.png"
    assert plot(["--out", str(out), f"run={run_dir}", f"copy={csv_file}"]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert out.read_bytes().startswith(b"\x89PNG")
    assert sorted(p.name for p in out.parent.iterdir()) == ["ablation.png"]


def _no_run(tmp_path, run_dir):
    return [f"a={tmp_path / 'nonexistent'}"], [
        "a=",
        "nonexistent: no such run directory",
        "LABEL=PATH",
    ]


def _no_label(tmp_path, run_dir):
    return [str(run_dir)], [f"run '{run_dir}': expected LABEL=PATH"]


def _empty_label(tmp_path, run_dir):
    return [f"={run_dir}"], ["expected LABEL=PATH, e.g. dense=runs/ablation/dense"]


def _empty_path(tmp_path, run_dir):
    return ["a="], ["run 'a=': expected LABEL=PATH"]


def _twice(tmp_path, run_dir):
    return [f"a={run_dir}", f"a={run_dir}"], ["label 'a' is given twice"]


def _no_validations(tmp_path, run_dir):
    (run_dir / "validations.csv").unlink()
    return [f"a={run_dir}"], [f"{run_dir}: no validations.csv", "eval_freq"]


def _not_a_csv(tmp_path, run_dir):
    (tmp_path / "model.zip").write_bytes(b"PK\x03\x04\x80\x81\xff")
    return [f"a={tmp_path / 'model.zip'}"], ["model.zip: cannot be read", "validations.csv"]


def _missing_column(tmp_path, run_dir):
    (run_dir / "validations.csv").write_text("step,capture_rate\n100,0.5\n")
    return [f"a={run_dir}"], ["validations.csv: no column median_ratio_to_limit"]


def _not_a_number(tmp_path, run_dir):
    (run_dir / "validations.csv").write_text(HEADER + "100,1.0,half,nan,nan\n")
    return [f"a={run_dir}"], ["line 2: column 'capture_rate' is 'half'; valid: a number"]


BAD_RUNS = [
    _no_run,
    _no_label,
    _empty_label,
    _empty_path,
    _twice,
    _no_validations,
    _not_a_csv,
    _missing_column,
    _not_a_number,
]


def _assert_refused(rc: int, capsys, expected: list[str], out: Path) -> None:
    assert rc == 2
    captured = capsys.readouterr()
    err = captured.err
    assert captured.out == ""
    assert err.startswith(PREFIX) and err.count("\n") == 1 and "Traceback" not in err
    for fragment in expected:
        assert fragment in err
    assert not out.is_file()


@pytest.mark.parametrize("case", BAD_RUNS, ids=lambda f: f.__name__.strip("_"))
def test_a_bad_run_is_one_line_and_exit_2(case, plot, run_dir, tmp_path, capsys):
    runs, expected = case(tmp_path, run_dir)
    out = tmp_path / "x.png"
    _assert_refused(plot(["--out", str(out), *runs]), capsys, expected, out)


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("x.foo", "unknown image suffix '.foo'; valid: "),
        ("x", "no image suffix; valid: "),
        ("a_folder", "a directory; give an image file"),
        ("a_file/x.png", "is a file, not a folder"),
    ],
)
def test_a_bad_out_is_one_line_and_exit_2(name, expected, plot, run_dir, tmp_path, capsys):
    (tmp_path / "a_folder").mkdir()
    (tmp_path / "a_file").write_text("")
    out = tmp_path / name
    rc = plot(["--out", str(out), f"a={run_dir}"])
    _assert_refused(rc, capsys, [expected, ".png"] if "valid" in expected else [expected], out)
    if name == "a_folder":
        assert list(out.iterdir()) == []


def test_run_as_a_script_a_nonexistent_run_is_one_line_without_a_traceback(tmp_path):
    result = subprocess.run(
        [sys.executable, str(SCRIPT), "--out", "x.png", "a=/nonexistent"],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr == (
        f"{PREFIX}a=/nonexistent: no such run directory or file; expected LABEL=PATH, "
        "e.g. dense=runs/ablation/dense (a train.py run directory or its validations.csv)\n"
    )
    assert list(tmp_path.iterdir()) == []
