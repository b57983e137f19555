"""A wheel built from the checkout works on its own: installed into a fresh virtual environment and
run from another directory, it registers every scenario and evaluates the quick suite."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
LEFT_OUT = shutil.ignore_patterns(
    ".git", "runs", "reports", "build", "dist", "*.egg-info", "__pycache__", ".*_cache", "tmp*"
)


def _run(args: list[str], cwd: Path, **kwargs) -> subprocess.CompletedProcess:
    result = subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=600, **kwargs)
    assert result.returncode == 0, f"{args} failed:\n{result.stdout}\n{result.stderr}"
    return result


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from a copy of the checkout."""
    if shutil.which("git") is None and not (ROOT / "configs").is_dir():
        pytest.skip("no checkout to build from")
    base = tmp_path_factory.mktemp("wheel")
    source = base / "source"  # a copy, so that no stale build/ of the checkout enters the wheel
    shutil.copytree(ROOT, source, ignore=LEFT_OUT)
    wheels = base / "wheels"
    _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(wheels), str(source)],
        cwd=base,
    )  # fmt: skip
    (built,) = wheels.glob("capture_bench-*.whl")
    return built


@pytest.fixture(scope="module")
def installed(wheel: Path) -> tuple[Path, Path]:
    """(the fresh environment's python, a working directory outside the checkout)."""
    base = wheel.parents[1]
    env_dir = base / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    python = env_dir / "bin" / "python"
    # The dependencies come from this interpreter's site-packages, added as a plain path: the
    # .pth files there (among them the checkout's editable install) are not processed, so the
    # only capture_bench the new environment can import is the wheel's.
    site = Path(_run([str(python), "-c", "import site; print(site.getsitepackages()[0])"],
                     cwd=base).stdout.strip())  # fmt: skip
    (site / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([str(python), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)], base)
    elsewhere = base / "elsewhere"
    elsewhere.mkdir()
    return python, elsewhere


def test_the_wheel_installs_one_import_name(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    top = {name.split("/")[0] for name in names}
    (dist_info,) = [t for t in top if t.endswith(".dist-info")]
    assert top - {dist_info} == {"capture_bench"}  # no top-level ``agents`` beside it
    assert "capture_bench/agents/protocol.py" in names
    assert "capture_bench/_data/configs/zoo/ppo.yml" in names  # the RL Zoo's files too
    top_level = f"{dist_info}/top_level.txt"
    if top_level in names:
        assert zipfile.ZipFile(wheel).read(top_level).decode().split() == ["capture_bench"]


def test_the_wheel_registers_every_scenario_from_another_directory(installed):
    python, elsewhere = installed
    code = (
        "import gymnasium, capture_bench, json; "
        "env = gymnasium.make('CaptureBench/Paper-v1'); env.reset(seed=0); "
        "env.step(env.action_space.sample()); env.close(); "
        "print(json.dumps([capture_bench.__file__, capture_bench.env_ids()]))"
    )
    where, ids = json.loads(_run([str(python), "-c", code], cwd=elsewhere).stdout)
    assert Path(where).is_relative_to(python.parents[1]), f"imported {where}, not the wheel"
    shipped = sorted(p.stem for p in (ROOT / "configs" / "scenarios").glob("*.yaml"))
    assert len(ids) == len(shipped) and "CaptureBench/Paper-v1" in ids


def test_the_console_script_writes_a_report(installed, tmp_path):
    python, elsewhere = installed
    script = python.parent / "capture-bench-evaluate"
    out = tmp_path / "out"
    _run([str(script), "--suite", "quick", "--workers", "1", "--out", str(out)], cwd=elsewhere)
    results = json.loads((out / "quick" / "results.json").read_text())
    assert {a["label"] for a in results["provenance"]["agents"]} == {"incremental_ik", "random"}
    assert (out / "quick" / "leaderboard.md").is_file()
    assert list(elsewhere.iterdir()) == []  # nothing written where it ran
    usage = _run([str(script), "--help"], cwd=elsewhere).stdout
    assert usage.startswith("usage: capture-bench-evaluate ")  # its own name, not evaluate.py


def test_python_m_capture_bench_runs_the_same_commands(installed):
    python, elsewhere = installed
    for command in ("evaluate", "train"):
        result = _run([str(python), "-m", "capture_bench", command, "--help"], cwd=elsewhere)
        assert f"usage: {command}.py" in result.stdout
    listing = _run([str(python), "-m", "capture_bench", "list"], cwd=elsewhere).stdout
    assert "_data/configs/scenarios" in listing and "CaptureBench/Paper-v1" in listing
