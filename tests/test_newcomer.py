"""What a newcomer runs into: a suite file named like a shipped suite, empty option values, the
console table in an 80-column log, the console scripts' names, and which machine made a report."""

from __future__ import annotations

import contextlib
import io
import json
import sys
from pathlib import Path

import pytest
from rich.console import Console

from capture_bench.evaluation import cli as evaluate_cli
from capture_bench.evaluation.reporting.aggregate import RankingRow
from capture_bench.evaluation.running.suites import SUITES_DIR, load_suite, shadowed_suite
from capture_bench.provenance import describe_machine, machine, provenance_text
from capture_bench.training.common import run as train_run
from capture_bench.training.tune import command as tune

ROOT = Path(__file__).parents[1]
COMMITTED = ROOT / "reports" / "published" / "default" / "results.json"
TINY_SUITE = """\
description: a newcomer's own suite, one agent, one scenario, one episode
agents: [incremental_ik]
scenarios: [paper]
episodes: 1
videos: false
"""
SHIPPED_MARKER = "the shipped default suite's report"


@pytest.fixture(scope="module")
def own_default_suite(tmp_path_factory) -> tuple[Path, Path, str, str]:
    """``evaluate.py --suite my/default.yaml`` (a user's file) next to an existing
    ``<out>/default/``: (out, suite file, stdout, stderr)."""
    root = tmp_path_factory.mktemp("own_suite")
    suite = root / "my" / "default.yaml"
    suite.parent.mkdir()
    suite.write_text(TINY_SUITE)
    out = root / "reports"
    (out / "default").mkdir(parents=True)
    (out / "default" / "leaderboard.md").write_text(SHIPPED_MARKER)
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        status = evaluate_cli.main(["--suite", str(suite), "--workers", "1", "--out", str(out)])
    assert status == 0, stderr.getvalue()
    return out, suite, stdout.getvalue(), stderr.getvalue()


def test_a_suite_file_named_like_a_shipped_suite_never_touches_its_report(own_default_suite):
    out, suite, stdout, stderr = own_default_suite
    assert (out / "default" / "leaderboard.md").read_text() == SHIPPED_MARKER
    assert sorted(p.name for p in (out / "default").iterdir()) == ["leaderboard.md"]
    (written,) = [p for p in out.iterdir() if p.name != "default"]
    assert written.name.startswith("custom-")
    assert written.name == load_suite(suite).name  # the same file always gets the same folder
    results = json.loads((written / "results.json").read_text())
    assert results["suite"] == written.name
    assert [r["agent"] for r in results["ranking"]] == ["incremental_ik"]
    title = (written / "leaderboard.md").read_text().splitlines()[0]
    assert "not a suite as defined" in title
    notes = [line for line in stderr.splitlines() if "note:" in line]
    assert any(f"{written}/" in n and f"{out / 'default'}/ is left" in n for n in notes), stderr
    assert f"report: {written}" in " ".join(stdout.split())


def test_the_shipped_suite_file_by_any_path_is_still_that_suite(tmp_path):
    assert load_suite(SUITES_DIR / "quick.yaml").name == "quick"
    assert load_suite(SUITES_DIR / ".." / "suites" / "default.yaml").name == "default"
    assert shadowed_suite("default") is None and shadowed_suite(SUITES_DIR / "quick.yaml") is None
    own = tmp_path / "mine.yaml"  # a name no shipped suite has keeps its own folder
    own.write_text(TINY_SUITE)
    assert load_suite(own).name == "mine" and shadowed_suite(own) is None
    copy = tmp_path / "quick.yml"  # a copy is not the shipped file
    copy.write_text((SUITES_DIR / "quick.yaml").read_text())
    assert shadowed_suite(copy) == "quick" and load_suite(copy).name.startswith("custom-")


def test_the_report_names_the_machine_that_made_it(own_default_suite):
    out, *_ = own_default_suite
    (written,) = [p for p in out.iterdir() if p.name != "default"]
    provenance = json.loads((written / "results.json").read_text())["provenance"]
    here = machine()
    assert provenance["machine"] == json.loads(json.dumps(here))
    assert {"cpu", "cores", "platform", "architecture", "simd", "blas"} <= set(here)
    assert here["cpu"] and here["cores"] >= 1 and here["platform"]
    for page in ("leaderboard.md", "leaderboard.html"):
        text = (written / page).read_text()
        assert "Provenance" in text and "bit for bit" in text, page
        assert str(here["cpu"]) in text and f"{here['cores']} cores" in text, page
        assert f"numpy {provenance['packages']['numpy']}" in text, page


def test_an_older_provenance_still_reads():
    older = json.loads(COMMITTED.read_text())["provenance"]  # machine: cpu, cores, system only
    assert older["machine"]["cpu"] in describe_machine(older)
    assert older["git"]["commit"][:12] in provenance_text(older)
    assert provenance_text({}) == "Computed on an unknown machine."


EMPTY_VALUES = [
    (evaluate_cli.main, "evaluate.py", ["--out", ""], "--out"),
    (evaluate_cli.main, "evaluate.py", ["--out="], "--out"),
    (evaluate_cli.main, "evaluate.py", ["--agents", ""], "--agents"),
    (evaluate_cli.main, "evaluate.py", ["--agents", ","], "--agents"),
    (evaluate_cli.main, "evaluate.py", ["--agents", "hold", ""], "--agents"),
    (evaluate_cli.main, "evaluate.py", ["--scenarios", ""], "--scenarios"),
    (evaluate_cli.main, "evaluate.py", ["--scenarios", " , "], "--scenarios"),
    (evaluate_cli.main, "evaluate.py", ["--suite", ""], "--suite"),
    (train_run.main, "train.py", ["--run-dir", ""], "--run-dir"),
    (train_run.main, "train.py", ["--scenario", ""], "--scenario"),
    (train_run.main, "train.py", ["--set", " "], "--set"),
    (tune.main, "tune.py", ["--output", ""], "--output"),
    (tune.main, "tune.py", ["--scenario", ""], "--scenario"),
    (tune.main, "tune.py", ["--keep", ""], "--keep"),
]


@pytest.mark.parametrize(
    ("main", "prog", "argv", "option"),
    EMPTY_VALUES,
    ids=[f"{prog} {' '.join(map(repr, argv))}" for _, prog, argv, _ in EMPTY_VALUES],
)
def test_an_empty_value_is_refused_in_one_line(
    main, prog, argv, option, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)  # where an empty --out or --run-dir would write
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert err == f"{prog}: error: argument {option}: expected a non-empty value" + (
        " (see --help)\n" if prog == "evaluate.py" else "\n"
    )
    assert out == "" and list(tmp_path.iterdir()) == []


def test_every_option_still_takes_its_values():
    from capture_bench.training.config import options
    from capture_bench.training.curves import command as curves

    config = evaluate_cli.parse_config(
        ["--agents", "hold,random", "incremental_ik", "--scenarios", "paper,", "--out", "x"]
    )
    assert config.agents == ["hold", "random", "incremental_ik"] and config.scenarios == ["paper"]
    assert config.out == Path("x") and config.suite == "default"  # a default string is checked
    trained, given = options.parse_args(["--set", "gamma=0.9", "--seed", "0", "--run-dir", "r"])
    assert trained.overrides == ["gamma=0.9"] and trained.seed == 0 and "run_dir" in given
    tuned = tune.build_parser().parse_args(["--keep", "net_arch", "--trials", "0"])
    assert tuned.keep == "net_arch" and tuned.trials == 0
    parsed = curves.build_parser().parse_args(["--algos", "sac", "--seeds", "1", "2"])
    assert parsed.algos == ["sac"] and parsed.seeds == [1, 2]


def test_a_bad_number_still_names_its_type(capsys):
    assert evaluate_cli.main(["--episodes", "x"]) == 2
    assert "argument --episodes: invalid int value: 'x'" in capsys.readouterr().err


def _ranking_rows() -> tuple[list[RankingRow], dict[tuple[str, str], float]]:
    """The committed default report's ranking and capture rates (16 agents, 8 scenarios)."""
    payload = json.loads(COMMITTED.read_text())

    rows = [RankingRow.from_json(r) for r in payload["ranking"]]
    rates = {(r["agent"], r["scenario"]): float(r["capture_rate"]) for r in payload["results"]}
    return rows, rates


def _render(width: int) -> str:
    rows, rates = _ranking_rows()
    console = Console(width=width, file=io.StringIO())
    console.print(evaluate_cli.summary_table("default", rows, rates, width))
    return console.file.getvalue()


def test_the_console_table_is_readable_at_80_columns():
    rows, _ = _ranking_rows()
    assert len(rows) >= 10
    text = _render(80)
    lines = text.splitlines()
    assert "…" not in text and max(len(line) for line in lines) <= 80
    for row in rows:
        (line,) = [line for line in lines if f" {row.agent} " in line]
        cells = line.replace("│", " ").split()
        assert f"{100 * row.mean_capture_rate:.0f}" in cells, line
        assert f"{row.mean_ratio_median:.2f}" in cells, line


def test_a_wide_console_shows_every_scenario():
    _, rates = _ranking_rows()
    header = next(line for line in _render(160).splitlines() if "agent" in line)
    assert all(scenario in header for _, scenario in rates)


@pytest.mark.parametrize(
    ("main", "script", "console_script"),
    [
        (evaluate_cli.main, "evaluate.py", "capture-bench-evaluate"),
        (train_run.main, "train.py", "capture-bench-train"),
        (tune.main, "tune.py", "capture-bench-tune"),
    ],
)
def test_a_console_script_goes_by_its_own_name(main, script, console_script, monkeypatch, capsys):
    assert main(["--help"]) == 0  # python evaluate.py, python -m capture_bench evaluate
    assert capsys.readouterr().out.startswith(f"usage: {script} ")
    monkeypatch.setattr(sys, "argv", [f"/venv/bin/{console_script}", "--help"])
    assert main(["--help"]) == 0
    assert capsys.readouterr().out.startswith(f"usage: {console_script} ")
    assert main(["--no-such-option"]) == 2
    assert capsys.readouterr().err.startswith(f"{console_script}: error: ")
