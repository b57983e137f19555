"""Numbers in the README and the documentation that cannot go stale: every generated block matches
its source (the published report, the model cards, the scenario files), a number changed by hand
is caught and named, the shipped-models table lists every shipped model, and no page carries the
project's lab log (commit hashes, notes of a past machine or run) outside code."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: Pages that quote the published report or the model cards, so must hold generated blocks. The
#: records of the v0 experiments (docs/results/generalist.md, sac_paper.md, grasp.md) quote the
#: report their retired models were judged by, as it was, and name it: no block.
QUOTING = (
    "README.md",
    "docs/index.md",
    "docs/evaluation.md",
    "docs/speed.md",
    "docs/results/leaderboard.md",
    "docs/results/models.md",
    "docs/results/envelope_rows.md",
)
#: A commit hash: a word of 7 to 40 hexadecimal digits with a digit and a letter in it (a seed or
#: a count has no letter; an English word has no digit).
HASH = re.compile(r"\b(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b")
#: A hash recorded as data in a generated page's provenance (``'commit': '…'``).
PROVENANCE_COMMIT = re.compile(r"'commit': '[0-9a-f]{7,40}'")
#: Notes of the project's history or of the machine a past figure came from.
LAB_LOG = tuple(
    re.compile(pattern, re.I)
    for pattern in (
        r"\bthis (2|two)-core machine\b",
        r"\bthe (shared )?(2|two)-core machine\b",
        r"\bshar(ing|ed) (the|its) (2|two) cores\b",
        r"\bon the (2|two) cores\b",
        r"\bon the other core\b",
        r"\bnothing else running\b",
        r"\bearlier (runs?|measurements?|regenerations?|commits?|reports?|pages?)\b",
        r"\b(before|after|since) the fix\b",
        r"\buntil now\b",
        r"\b(at|commit|commits|against|before|after) `[0-9a-f]{7,40}`",  # a hash of digits only
    )
)
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
CODE_SPAN = re.compile(r"(`+)(.+?)\1", re.S)


@pytest.fixture(scope="module")
def blocks(readme_table):
    return readme_table._blocks(readme_table.RESULTS)


def _pages() -> list[Path]:
    return [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]


def test_every_page_with_blocks_matches_its_sources(readme_table, capsys):
    found = {p.relative_to(ROOT).as_posix() for p in readme_table.default_files()}
    assert set(QUOTING) <= found, f"pages without generated blocks: {set(QUOTING) - found}"
    status = readme_table.main(["--check"])
    assert status == 0, capsys.readouterr().err


def _plant(body: str) -> str:
    """``body`` with its first digit changed."""
    match = re.search(r"\d", body)
    assert match is not None
    digit = str((int(match.group()) + 1) % 10)
    return body[: match.start()] + digit + body[match.end() :]


def test_a_changed_number_in_any_block_is_caught_and_named(readme_table, blocks):
    planted = 0
    for path in readme_table.default_files():
        text = path.read_text()
        for match in readme_table.BLOCK.finditer(text):
            body = match.group("body")
            if not re.search(r"\d", body):
                continue
            wrong = text[: match.start("body")] + _plant(body) + text[match.end("body") :]
            _, _, stale = readme_table.regenerate(wrong, blocks)
            assert stale == [match.group("tag")], f"{path.name}: {match.group('tag')}"
            planted += 1
    assert planted >= 20  # the report's counts, its tables, the models and scenarios


@pytest.mark.parametrize(
    ("page", "tag"),
    [("docs/evaluation.md", "report-summary"), ("docs/index.md", "report episodes")],
)
def test_the_check_fails_on_a_copy_with_one_digit_changed_naming_the_block(
    readme_table, tmp_path, capsys, page, tag
):
    text = (ROOT / page).read_text()
    match = next(m for m in readme_table.BLOCK.finditer(text) if m.group("tag") == tag)
    copy = tmp_path / Path(page).name
    copy.write_text(
        text[: match.start("body")] + _plant(match.group("body")) + text[match.end("body") :]
    )
    assert readme_table.main(["--check", str(copy)]) == 1
    err = capsys.readouterr().err
    assert f"{copy} ({tag})" in err, err
    assert readme_table.main([str(copy)]) == 0
    assert copy.read_text() == text


def test_a_value_block_refuses_a_table_and_unknown_keys(readme_table, tmp_path, capsys):
    page = tmp_path / "page.md"
    page.write_text("a <!-- models:start -->x<!-- models:end --> b\n")
    assert readme_table.main(["--check", str(page)]) == 2
    assert "holds a value, not a table" in capsys.readouterr().err
    page.write_text("a <!-- report speed:start -->x<!-- report speed:end --> b\n")
    assert readme_table.main(["--check", str(page)]) == 2
    assert "unknown key 'speed'" in capsys.readouterr().err
    page.write_text("Text,\n<!-- report agents:start -->1<!-- report agents:end --> agents.\n")
    assert readme_table.main(["--check", str(page)]) == 2
    assert "starts a line" in capsys.readouterr().err
    page.write_text("<!-- published-cells nobody:start -->\n<!-- published-cells nobody:end -->\n")
    assert readme_table.main(["--check", str(page)]) == 2
    assert "no agent 'nobody'" in capsys.readouterr().err


def test_a_marker_in_a_code_span_is_text(readme_table, blocks):
    text = "Blocks sit between `<!-- NAME:start -->` and `<!-- NAME:end -->`.\n"
    assert readme_table.regenerate(text, blocks) == (text, [], [])


def test_the_models_table_lists_every_shipped_model(readme_table):
    carded = sorted(
        p.parent.name
        for p in (ROOT / "models").glob("*/metadata.json")
        if "model_card" in json.loads(p.read_text())
    )
    assert carded == sorted(p.name for p in (ROOT / "models").iterdir() if p.is_dir())
    page = (DOCS / "results" / "models.md").read_text()
    table = re.search(r"<!-- models:start -->\n(.*?)<!-- models:end -->", page, re.S)
    assert table is not None, "docs/results/models.md has no models block"
    listed = re.findall(r"^\| `([^`]+)` \|", table.group(1), re.M)
    assert listed == carded
    assert {"ppo-pixels-paper", "ppo-pixels-grasp"} <= set(listed)


def _prose(text: str) -> str:
    """``text`` without fenced code blocks; a code span stays only where it is nothing but a
    hash-like word (a reference to a commit, not a command or a path that holds one as data)."""
    text = FENCE.sub("", text)
    return CODE_SPAN.sub(lambda m: m.group(2) if HASH.fullmatch(m.group(2).strip()) else "", text)


def test_no_page_carries_the_lab_log():
    problems = []
    for path in _pages():
        text = FENCE.sub("", path.read_text())
        prose = PROVENANCE_COMMIT.sub("", _prose(text))
        name = path.relative_to(ROOT).as_posix()
        problems += [f"{name}: commit hash {m.group()}" for m in HASH.finditer(prose)]
        for pattern in LAB_LOG:
            problems += [f"{name}: {m.group()!r}" for m in pattern.finditer(text)]
    assert not problems, "history belongs in git or CHANGELOG.md:\n" + "\n".join(problems)


def test_the_lab_log_lint_can_fail():
    text = "Measured at `5a6660c` on this 2-core machine.\n```\ngit checkout 5a6660c\n```\n"
    prose = _prose(text)
    assert [m.group() for m in HASH.finditer(prose)] == ["5a6660c"]
    assert any(p.search(prose) for p in LAB_LOG)
    assert any(p.search("the run at `8801270`") for p in LAB_LOG)
    assert not any(p.search("seed `1000000` draws") for p in LAB_LOG)
    assert not HASH.search(_prose("`git worktree add /tmp/b c8c4260` and seed 1000000\n"))
