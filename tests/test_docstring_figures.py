"""No docstring or comment under ``capture_bench/`` quotes a measured timing: a figure in ``us``,
``µs``, ``ns`` or ``ms`` next to a cost word (``costs``, ``takes``, ``pays``, ``faster``,
``slower``, ``a call``, ``per call``, ``per update``, ``a frame``, ``ms/predict``, ...), or a
speed-up (``4x faster``, ``times slower``). Such figures go
stale with the code and the machine; they live in ``docs/speed.md``'s tables, each under the
command in ``benchmarks/`` that measured it, and the code says which is faster and why in words.
Settings in those units (a GIF's ``10 ms`` delay unit, an exposure ``at 20 ms``) pass: no cost
word stands beside them. Docstrings are read with `ast`, comments with `tokenize`; nothing is
imported."""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: A duration of computing: a number and a unit of time too short for anything simulated here.
_FIGURE = r"\d+(?:[.,]\d+)?\s*(?:us|µs|μs|ns|ms)\b"
#: Words that make such a figure a cost.
_COST = (
    r"\bcosts?\b|\btakes?\b|\bpays\b|\bfaster\b|\bslower\b"
    r"|\b(?:an?|per)\s+(?:call|update|step|frame|image|capture|pose|episode)\b|/\s*(?:call|predict)"
)
#: How many characters on either side of a figure the cost word may stand.
_NEAR = 40
_TIMED = re.compile(
    rf"(?:{_COST})[^.;]{{0,{_NEAR}}}?{_FIGURE}|{_FIGURE}[^.;]{{0,{_NEAR}}}?(?:{_COST})",
    re.IGNORECASE,
)
_SPEED_UP = re.compile(r"(?:\d+(?:\.\d+)?\s*x|\btimes)\s+(?:faster|slower)\b", re.IGNORECASE)


def _texts(source: str) -> list[tuple[int, str]]:
    """(first line, text) of every string statement (docstrings, attribute docstrings) and of
    every run of comments on consecutive lines, ``#`` and ``#:`` left out."""
    texts = [
        (node.lineno, node.value.value)
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Expr)
        and isinstance(node.value, ast.Constant)
        and isinstance(node.value.value, str)
    ]
    run_start, run, last = 0, [], -1
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type != tokenize.COMMENT:
            continue
        line = token.start[0]
        if line != last + 1 and run:
            texts.append((run_start, "\n".join(run)))
            run = []
        if not run:
            run_start = line
        run.append(token.string.lstrip("#:").strip())
        last = line
    if run:
        texts.append((run_start, "\n".join(run)))
    return texts


def quoted_timings(package: Path) -> list[str]:
    """``path:line: text`` of each measured timing in the docstrings and comments of the modules
    under ``package``, paths relative to ``package``'s parent."""
    found: set[tuple[str, int, str]] = set()
    for path in sorted(package.rglob("*.py")):
        name = path.relative_to(package.parent)
        for first, text in _texts(path.read_text(encoding="utf-8")):
            for pattern in (_TIMED, _SPEED_UP):
                for match in pattern.finditer(text):
                    line = first + text.count("\n", 0, match.start())
                    found.add((str(name), line, " ".join(match.group().split())))
    return [f"{name}:{line}: {text}" for name, line, text in sorted(set(found))]


def test_no_docstring_or_comment_quotes_a_timing() -> None:
    found = quoted_timings(ROOT / "capture_bench")
    assert not found, (
        "measured figures in docstrings or comments (say which is faster and why, and point to "
        "the benchmark script and docs/speed.md instead):\n" + "\n".join(found)
    )


def test_the_check_finds_planted_timings(tmp_path: Path) -> None:
    module = '''"""A module.

The update takes 38 us against filterpy's 45.
"""

GIF_UNIT = 10  # delays in the GIF's 10 ms units, at least 20 ms


def f():
    """The batched filter is ~4x faster at n = 64; several times faster in all."""
    # LAPACK directly: np.linalg.solve costs
    # ~13 us per call here.
    return 1


EXPOSURE = 0.02
"""Exposure at 20 ms: a smear of 7 px at 0.2 m/s."""
'''
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "mod.py").write_text(module, encoding="utf-8")
    assert quoted_timings(tmp_path / "pkg") == [
        "pkg/mod.py:3: takes 38 us",
        "pkg/mod.py:10: 4x faster",
        "pkg/mod.py:10: times faster",
        "pkg/mod.py:11: costs ~13 us",
    ]
