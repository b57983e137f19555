"""The published leaderboard and a user's run are two things: ``python evaluate.py`` writes its own
report and compares it with the published one value by value; only ``--publish`` writes the
published folder, and nothing else may write inside it."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest

from capture_bench.evaluation import cli as evaluate_cli
from capture_bench.evaluation.reporting import reproduction
from capture_bench.evaluation.reporting.reproduction import compare, read_published

ROOT = Path(__file__).parents[1]
QUICK = ["--suite", "quick", "--workers", "1"]


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory) -> Path:
    """The quick suite's report, played once (12 episodes)."""
    out = tmp_path_factory.mktemp("quick")
    assert evaluate_cli.main([*QUICK, "--out", str(out)]) == 0
    return out / "quick"


@pytest.fixture
def published(tmp_path, quick_report, monkeypatch) -> Path:
    """A published folder holding a copy of the quick report."""
    folder = tmp_path / "published"
    shutil.copytree(quick_report, folder / "quick")
    monkeypatch.setattr(reproduction, "published_dir", lambda: folder)
    return folder


def _plant(folder: Path) -> None:
    """A published capture rate no run of these episodes could give, and one episode that
    ended otherwise."""
    results = json.loads((folder / "results.json").read_text())
    row = next(r for r in results["results"] if r["agent"] == "incremental_ik")
    row["capture_rate"] = 0.05
    (folder / "results.json").write_text(json.dumps(results))
    with (folder / "episodes.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    first = next(r for r in rows if r["agent"] == "random")
    first["outcome"], first["failure"] = "captured", ""
    with (folder / "episodes.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def test_a_run_of_the_published_episodes_reproduces_every_value(quick_report, published):
    comparison = compare(read_published(quick_report), read_published(published / "quick"))
    assert comparison.reproduced and comparison.same_machine_kind
    assert len(comparison.checks) == 8  # 2 agents x 2 scenarios x (capture rate, median ratio)
    assert comparison.identical == comparison.episodes == 12


def test_the_comparison_names_a_planted_difference(quick_report, published):
    _plant(published / "quick")
    comparison = compare(read_published(quick_report), read_published(published / "quick"))
    assert not comparison.reproduced
    (difference,) = comparison.differences
    assert (difference.agent, difference.metric) == ("incremental_ik", "capture_rate")
    assert difference.describe().startswith("incremental_ik on paper: capture rate 0.050 published")
    assert comparison.other_outcome == ["random paper 1000000"]


def test_evaluate_ends_with_the_comparison_and_writes_it_into_its_own_report(
    published, tmp_path, capsys
):
    _plant(published / "quick")
    before = sorted((published / "quick").iterdir())
    assert evaluate_cli.main([*QUICK, "--out", str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out
    assert "against the published report" in out
    assert "reproduced 7 of 8 values" in out
    assert "differs: incremental_ik on paper: capture rate 0.050 published" in out
    assert "1 ended otherwise (random paper 1000000)" in out
    written = json.loads((tmp_path / "run" / "quick" / "reproduction.json").read_text())
    assert written["values_reproduced"] == 7 and not written["reproduced"]
    assert (
        "incremental_ik | paper | capture rate"
        in (tmp_path / "run" / "quick" / "reproduction.md").read_text()
    )
    assert sorted((published / "quick").iterdir()) == before  # the published report untouched


@pytest.mark.parametrize(
    "option",
    [
        ["--out", "{published}"],
        ["--out", "{published}/quick/inside"],
        ["--out", "{published}/.."],  # its report folder would replace the published folder
        ["--video", "{published}/videos"],
        ["--episode-plots", "{published}/quick"],
    ],
)
def test_nothing_but_publish_writes_inside_the_published_folder(
    option, published, tmp_path, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    before = {p: p.stat().st_mtime_ns for p in published.rglob("*")}
    argv = [*QUICK, *(a.format(published=published) for a in option)]
    if option[0] == "--out" and option[1].endswith(".."):
        (tmp_path / "suites").mkdir()  # a suite named like the published folder
        shutil.copy(
            ROOT / "configs" / "suites" / "quick.yaml", tmp_path / "suites" / "published.yaml"
        )
        argv[1] = str(tmp_path / "suites" / "published.yaml")
    assert evaluate_cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "only python evaluate.py --publish writes" in err, err
    assert {p: p.stat().st_mtime_ns for p in published.rglob("*")} == before


@pytest.mark.parametrize(
    "extra", [["--agents", "incremental_ik"], ["--episodes", "2"], ["--seed-set", "validation"]]
)
def test_publish_takes_only_a_shipped_suite_as_defined(extra, published, capsys):
    assert evaluate_cli.main([*QUICK, "--publish", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--publish writes" in err and "as defined" in err


def test_publish_takes_no_out_of_its_own(published, tmp_path, capsys):
    assert evaluate_cli.main([*QUICK, "--publish", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "takes no --out" in err and not (tmp_path / "x").exists()


def test_publish_replaces_the_published_report_and_compares_with_the_previous_one(
    published, capsys
):
    _plant(published / "quick")
    assert evaluate_cli.main([*QUICK, "--publish"]) == 0
    out = capsys.readouterr().out
    assert "(before this run)" in out and "reproduced 7 of 8" in out
    assert not (published / "quick" / "reproduction.md").exists()  # only the report itself
    fresh = json.loads((published / "quick" / "results.json").read_text())
    assert next(r for r in fresh["results"] if r["agent"] == "incremental_ik")["capture_rate"] > 0.5


def test_the_published_leaderboard_is_committed_and_a_users_run_is_ignored():
    """``reports/published/`` is tracked; what ``python evaluate.py`` writes by default
    (``reports/<suite>/``) is git-ignored, so the checkout stays clean after it."""
    import subprocess

    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")

    def ignored(path: str) -> bool:
        done = subprocess.run(["git", "check-ignore", "-q", path], cwd=ROOT, timeout=30)
        return done.returncode == 0

    assert ignored("reports/default/results.json") and ignored("reports/custom-1234/x.png")
    assert not ignored("reports/published/default/results.json")
    assert (ROOT / "reports" / "published" / "default" / "results.json").is_file()


def test_a_value_without_an_interval_is_reproduced_only_by_its_equal():
    """A median of too few captures has no bootstrap interval: then the published value must
    equal the run's (the same machine's case); an infinite median equals an infinite one."""
    check = reproduction.ValueCheck
    nan, inf = float("nan"), float("inf")
    assert check("a", "s", "ratio_median", 6.386, 6.386, nan, nan).reproduced
    assert not check("a", "s", "ratio_median", 6.386, 6.4, nan, nan).reproduced
    assert check("a", "s", "ratio_median", inf, inf, nan, nan).reproduced
    assert check("a", "s", "ratio_median", nan, nan, nan, nan).reproduced
    assert not check("a", "s", "ratio_median", 2.0, nan, nan, nan).reproduced
    assert check("a", "s", "capture_rate", 0.0, 0.0, 5.6e-17, 0.56).reproduced  # Wilson's 0


def test_a_published_report_this_code_cannot_read_is_named_not_compared(
    published, tmp_path, capsys
):
    episodes = published / "quick" / "episodes.csv"
    episodes.write_text(episodes.read_text().replace("relative_speed_at_capture,", "", 1))
    assert evaluate_cli.main([*QUICK, "--out", str(tmp_path / "run")]) == 0
    captured = capsys.readouterr()
    assert "cannot be read as a report of this code's" in captured.err
    assert "against the published report" not in captured.out
    assert not (tmp_path / "run" / "quick" / "reproduction.md").exists()
