"""``evaluate.py --merge``: reports evaluated apart (one agent per machine) merge into the report of
one evaluation of every agent; reports that did not play the same game are refused in one line,
before anything is written; ``episodes.csv`` reads back exactly."""

from __future__ import annotations

import csv
import json
import math
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from test_evaluation_metrics import record

from capture_bench.evaluation.errors import EvaluationError
from capture_bench.evaluation.reporting.aggregate import (
    RESULT_TIMING_COLUMNS,
    rank_agents,
    summarise_all,
)
from capture_bench.evaluation.reporting.report import (
    ReportData,
    csv_value,
    read_episodes,
    write_report,
)
from capture_bench.evaluation.running.rollout import EPISODE_COLUMNS, TIMING_COLUMNS, EpisodeRecord
from evaluate import main

AGENTS = ["incremental_ik", "pure_pursuit"]
SELECTION = ["--scenarios", "paper", "drift", "--episodes", "3", "--workers", "1"]


def _evaluate(agents: list[str], out: Path, *extra: str) -> Path:
    assert main(["--agents", *agents, *SELECTION, *extra, "--out", str(out)]) == 0
    (report,) = out.iterdir()
    return report


@pytest.fixture(scope="module")
def reports(tmp_path_factory) -> dict[str, Path]:
    """One evaluation of both agents (``full``), one of each (``ik``, ``pursuit``), and one of
    pure_pursuit on two seeds per scenario (``short``)."""
    root = tmp_path_factory.mktemp("reports")
    return {
        "full": _evaluate(AGENTS, root / "full"),
        "ik": _evaluate(AGENTS[:1], root / "ik"),
        "pursuit": _evaluate(AGENTS[1:], root / "pursuit"),
        "short": _evaluate(AGENTS[1:], root / "short", "--episodes", "2"),
    }


def _rows(path: Path, left_out: frozenset[str] = frozenset()) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return [
            {k: v for k, v in row.items() if k not in left_out} for row in csv.DictReader(handle)
        ]


def _tables(report: Path) -> list[str]:
    """The lines of leaderboard.md's tables and section titles (the page's title and provenance
    name the run, not the results)."""
    lines = (report / "leaderboard.md").read_text().splitlines()
    return [line for line in lines if line.startswith(("|", "## ", "### "))]


def _merge(dirs: list[Path], out: Path) -> Path:
    assert main(["--merge", *map(str, dirs), "--out", str(out)]) == 0
    (merged,) = out.iterdir()
    return merged


def _assert_same_tables(merged: Path, full: Path) -> None:
    assert _rows(merged / "results.csv", RESULT_TIMING_COLUMNS) == _rows(
        full / "results.csv", RESULT_TIMING_COLUMNS
    )
    assert _rows(merged / "episodes.csv", TIMING_COLUMNS) == _rows(
        full / "episodes.csv", TIMING_COLUMNS
    )
    ranking = [json.loads((p / "results.json").read_text())["ranking"] for p in (merged, full)]
    assert ranking[0] == ranking[1]
    assert _tables(merged) == _tables(full)


def test_two_halves_merge_into_the_full_evaluation(reports, tmp_path, capsys):
    merged = _merge([reports["ik"], reports["pursuit"]], tmp_path)
    assert merged.name.startswith("merged-")
    _assert_same_tables(merged, reports["full"])
    gifs = sorted(p.name for p in merged.glob("*.gif"))  # the episodes to watch, carried over
    assert gifs == sorted(p.name for p in reports["full"].glob("*.gif")) and len(gifs) == 2
    for name in gifs:
        assert (merged / name).read_bytes() == (reports["ik"] / name).read_bytes()
    provenance = json.loads((merged / "results.json").read_text())["provenance"]
    sources = provenance["merged_from"]
    assert [s["report"] for s in sources] == [str(reports["ik"]), str(reports["pursuit"])]
    assert all(s["command"].startswith("python evaluate.py --agents") for s in sources)
    assert all("cpu" in s["machine"] for s in sources)
    assert provenance["command"].startswith("python evaluate.py --merge")
    assert provenance["videos"] == "2 GIFs carried over from the source reports"
    md = (merged / "leaderboard.md").read_text()
    assert "Merged from 2 reports:" in md and "(reports merged from several evaluations)" in md
    assert f"report: {merged}" in " ".join(capsys.readouterr().out.split())


def test_identical_duplicates_are_kept_once_and_a_merge_again_replaces_its_folder(
    reports, tmp_path
):
    dirs = [reports["ik"], reports["full"], reports["pursuit"]]
    merged = _merge(dirs, tmp_path)
    _assert_same_tables(merged, reports["full"])
    assert _merge(dirs, tmp_path) == merged  # the same name; replaced whole, no staging left
    assert [p.name for p in tmp_path.iterdir()] == [merged.name]


def _copy(report: Path, tmp_path: Path, name: str) -> Path:
    return Path(shutil.copytree(report, tmp_path / name))


def _edit_results(report: Path, change: Callable[[dict], None]) -> Path:
    payload = json.loads((report / "results.json").read_text())
    change(payload)
    (report / "results.json").write_text(json.dumps(payload))
    return report


def _write_rows(path: Path, rows: list[dict[str, str]]) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


def _edit_episode(report: Path, row: int, column: str, value: str) -> Path:
    rows = _rows(report / "episodes.csv")
    rows[row][column] = value
    _write_rows(report / "episodes.csv", rows)
    return report


def _truncated_json(report: Path) -> Path:
    (report / "results.json").write_text('{"suite": "x", ')
    return report


def _only_paper(report: Path) -> Path:
    """The report as if evaluated on paper only (its drift episodes and seeds removed)."""
    rows = [r for r in _rows(report / "episodes.csv") if r["scenario"] == "paper"]
    _write_rows(report / "episodes.csv", rows)

    def drop_drift(payload: dict) -> None:
        del payload["provenance"]["seeds"]["drift"]
        del payload["provenance"]["config_hashes"]["scenarios"]["drift"]

    return _edit_results(report, drop_drift)


def _set(*keys: str, value) -> Callable[[dict], None]:
    def change(payload: dict) -> None:
        for key in keys[:-1]:
            payload = payload[key]
        payload[keys[-1]] = value

    return change


def _model_files(digest: str) -> Callable[[dict], None]:
    """Calls incremental_ik a model whose files hash to ``digest`` (in config_hashes only)."""
    return _set(
        "provenance",
        "config_hashes",
        "models",
        value={"incremental_ik": {"sha256": {"policy.pt": digest}}},
    )


def test_a_source_with_uncommitted_changes_is_noted_and_the_merge_says_dirty(
    reports, tmp_path, capsys
):
    dirty = _edit_results(
        _copy(reports["pursuit"], tmp_path, "dirty"), _set("provenance", "git", "dirty", value=True)
    )
    merged = _merge([reports["ik"], dirty], tmp_path / "out")
    assert f"evaluate.py: note: {dirty} was computed with uncommitted changes" in (
        capsys.readouterr().err
    )
    provenance = json.loads((merged / "results.json").read_text())["provenance"]
    assert provenance["git"]["dirty"] is True
    assert "with uncommitted changes" in (merged / "leaderboard.md").read_text()


#: name -> (the report folders to merge, from the fixture's and tmp_path; a fragment of the error)
MISMATCHES: dict[str, tuple[Callable[[dict[str, Path], Path], list[Path]], str]] = {
    "other seeds": (
        lambda r, t: [r["ik"], r["short"]],
        "scenario 'paper' played on 2 seeds (1000000 to 1000001), but",
    ),
    "other scenarios": (
        lambda r, t: [r["ik"], _only_paper(_copy(r["pursuit"], t, "paper"))],
        "scenarios paper, but",
    ),
    "a scenario file changed": (
        lambda r, t: [
            r["ik"],
            _edit_results(
                _copy(r["pursuit"], t, "hash"),
                _set("provenance", "config_hashes", "scenarios", "drift", value="0" * 64),
            ),
        ],
        "scenario 'drift' is another file than in",
    ),
    "another commit": (
        lambda r, t: [
            r["ik"],
            _edit_results(
                _copy(r["pursuit"], t, "commit"),
                _set("provenance", "git", "commit", value="f" * 40),
            ),
        ],
        "computed at commit ffffffffffffffffffffffffffffffffffffffff, but",
    ),
    "another capture-bench version": (
        lambda r, t: [
            r["ik"],
            _edit_results(
                _copy(r["pursuit"], t, "version"),
                _set("provenance", "packages", "capture-bench", value="9.9.9"),
            ),
        ],
        "capture-bench 9.9.9, but",
    ),
    "another reference": (
        lambda r, t: [
            r["ik"],
            _edit_results(
                _copy(r["pursuit"], t, "reference"), _set("reference", value="pure_pursuit")
            ),
        ],
        "reference agent 'pure_pursuit', but",
    ),
    "a conflicting duplicate episode": (
        lambda r, t: [
            r["ik"],
            _edit_episode(_copy(r["full"], t, "conflict"), 1, "capture_time", "9.5"),
        ],
        "disagree on the episode of incremental_ik on paper seed 1000001 (capture_time:",
    ),
    "one model label, other files": (
        lambda r, t: [
            _edit_results(_copy(r["ik"], t, "model-a"), _model_files("a" * 64)),
            _edit_results(_copy(r["full"], t, "model-b"), _model_files("b" * 64)),
        ],
        "model 'incremental_ik' is not the files of",
    ),
    "a folder that is no report": (
        lambda r, t: [r["ik"], Path(t / "empty").resolve()],
        "not a report folder written by evaluate.py (no results.json)",
    ),
    "a missing folder": (lambda r, t: [r["ik"], t / "nowhere"], "nowhere: no such report folder"),
    "a corrupt results.json": (
        lambda r, t: [r["ik"], _truncated_json(_copy(r["pursuit"], t, "json"))],
        "results.json: not valid JSON",
    ),
    "a results.json of another shape": (
        lambda r, t: [
            r["ik"],
            _edit_results(_copy(r["pursuit"], t, "shape"), _set("provenance", "seeds", value=[1])),
        ],
        "provenance 'seeds' is missing or not a dict; not a results.json written by evaluate.py",
    ),
    "an unreadable number in episodes.csv": (
        lambda r, t: [r["ik"], _edit_episode(_copy(r["pursuit"], t, "csv"), 2, "steps", "many")],
        "episodes.csv: line 4: column 'steps': 'many' cannot be read as int",
    ),
    "an episodes.csv that is not its results.json's": (
        lambda r, t: [r["ik"], _edit_episode(_copy(r["pursuit"], t, "rows"), 2, "seed", "7")],
        "(pure_pursuit on paper seed 7 where pure_pursuit on paper seed 1000002 belongs)",
    ),
    "one folder": (lambda r, t: [r["ik"]], "--merge takes two or more report folders"),
    "one folder twice": (lambda r, t: [r["ik"], r["ik"]], "is named twice"),
}


@pytest.mark.parametrize("case", list(MISMATCHES))
def test_a_mismatch_is_refused_in_one_line_and_nothing_is_written(case, reports, tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    make, fragment = MISMATCHES[case]
    dirs = make(reports, tmp_path)
    out = tmp_path / "out"
    assert main(["--merge", *map(str, dirs), "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured.err
    assert captured.err.startswith("evaluate.py: error: ") and fragment in captured.err
    assert not out.exists()


@pytest.mark.parametrize(
    "option", [["--agents", "hold"], ["--workers", "2"], ["--suite", "quick"], ["--video", "v"]]
)
def test_merge_refuses_the_options_that_play_episodes(option, reports, tmp_path, capsys):
    argv = ["--merge", str(reports["ik"]), str(reports["pursuit"]), *option, "--out", str(tmp_path)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"so {option[0]} does not apply" in err
    assert list(tmp_path.iterdir()) == []


def _exact(a: object, b: object) -> bool:
    """Equal to the last bit: same type, NaN equal to NaN, the sign of a zero kept."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return (math.isnan(a) and math.isnan(b)) or (
            a == b and math.copysign(1, a) == math.copysign(1, b)
        )
    return a == b


def _assert_round_trip(written: list[EpisodeRecord], read: list[EpisodeRecord]) -> None:
    assert len(read) == len(written)
    for mine, theirs in zip(written, read):
        for column in EPISODE_COLUMNS:
            assert _exact(getattr(mine, column), getattr(theirs, column)), column


def test_episodes_csv_reads_back_every_field_exactly(tmp_path):
    awkward = [
        record("a", 7, 0.1 + 0.2, wall_clock_s=1e-300, cpu_s=5e-324),
        record("a", 8, None, failure="target_lost", physical_limit_time=math.inf, mean_nees=-0.0),
        record('b, "quoted"', 2**40, 1 / 3, saturated_share=math.nan, steps=0, cpu_s=math.nan),
        record(
            'b, "quoted"',
            9,
            None,
            capture_time_estimated=2.5e-17,
            path_length=1.7976931348623157e308,
        ),
    ]
    summaries = summarise_all(awkward)
    data = ReportData(
        "csv",
        "round trip",
        "python evaluate.py",
        "a",
        awkward,
        summaries,
        rank_agents(summaries),
        {},
    )
    read = read_episodes(write_report(data, tmp_path) / "episodes.csv")
    _assert_round_trip(awkward, read)
    assert read[1].failure == "target_lost" and read[0].failure == ""  # str, never NaN


def test_an_evaluation_episodes_csv_reads_back_as_written(reports):
    path = reports["full"] / "episodes.csv"
    read = read_episodes(path)
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(read) == len(rows) == 12
    for row, episode in zip(rows, read):  # written again, every cell is the text read
        assert {k: str(csv_value(v)) for k, v in episode.as_row().items()} == row


def test_an_episodes_csv_without_a_column_is_named(tmp_path):
    (tmp_path / "episodes.csv").write_text("agent,scenario\nx,paper\n")
    with pytest.raises(EvaluationError, match="episodes.csv: line 2: no column 'seed'"):
        read_episodes(tmp_path / "episodes.csv")


def test_merge_without_rliable_is_one_line_before_anything_is_written(
    reports, tmp_path, capsys, monkeypatch
):
    from capture_bench import rliable_stats

    monkeypatch.setattr(rliable_stats, "installed", lambda: False)
    argv = ["--merge", str(reports["ik"]), str(reports["pursuit"]), "--out", str(tmp_path)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install rliable" in err
    assert list(tmp_path.iterdir()) == []
