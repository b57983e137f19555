"""The command-line parser every CLI uses: every mistake is one line on stderr and exit status 2."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

#: The prefix of the console scripts ``pyproject.toml`` installs (``capture-bench-evaluate``).
CONSOLE_SCRIPT_PREFIX = "capture-bench-"
#: argparse's ``nargs`` that gather a list; their items may be comma-separated lists.
LIST_NARGS = ("+", "*")


def program(script: str) -> str:
    """The name a command goes by in its usage line and its errors.

    ``script`` is the checkout's script (``evaluate.py``); when this process was started as the
    matching console script (``capture-bench-evaluate``, the basename of ``sys.argv[0]``), that
    name instead. ``python -m capture_bench evaluate`` and a call of ``main`` from Python keep
    ``script``.
    """
    started_as = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    console = CONSOLE_SCRIPT_PREFIX + Path(script).stem
    return console if started_as.removesuffix(".exe") == console else script


def _non_empty(convert: Callable[[str], Any] | None, listed: bool) -> Callable[[str], Any]:
    """``convert`` (identity for None), refusing an empty or blank value first and, for a list
    option (``listed``), a value that splits at commas into nothing (``,``): argparse would
    turn ``--out ""`` into ``Path(".")`` and ``--agents ""`` into "no selection"."""

    def check(value: str) -> Any:
        parts = value.split(",") if listed else [value]
        if not any(part.strip() for part in parts):
            raise argparse.ArgumentTypeError("expected a non-empty value")
        return value if convert is None else convert(value)

    # argparse names the type in its errors ("invalid int value: 'x'"): keep the name
    check.__name__ = getattr(convert, "__name__", "str")
    return check


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a bad option in one line, ``<prog>: error: <message><hint>``, and
    exits with status 2 (argparse's own also prints the usage).

    Every option that takes a value refuses an empty or blank one (``--out ""``,
    ``--agents ""``, ``--agents ,``) as ``argument --out: expected a non-empty value``.

    Args:
        prog: the script's name (``evaluate.py``); shown as the console script's name when the
            process runs as that script (`program`).
        hint: appended to every error, e.g. ``" (see --help)"``.
    """

    def __init__(self, *args: Any, prog: str | None = None, hint: str = "", **kwargs: Any) -> None:
        kwargs["prog"] = None if prog is None else program(prog)
        super().__init__(*args, **kwargs)
        self.hint = hint

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        action = super().add_argument(*args, **kwargs)
        takes_values = action.nargs not in (0, argparse.PARSER, argparse.REMAINDER)
        if takes_values and (action.type is None or callable(action.type)):  # not --help, flags
            action.type = _non_empty(action.type, action.nargs in LIST_NARGS)  # type: ignore[arg-type]
        return action

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message}{self.hint}", file=sys.stderr)
        raise SystemExit(2)

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:  # type: ignore[override]
        """argparse's, but ``--workers=--`` is an error: argparse (3.11) makes its value ``[]``."""
        parsed, extras = super().parse_known_args(args, namespace)
        for action in self._actions:
            if action.nargs is None and getattr(parsed, action.dest, None) == []:
                self.error(f"argument {action.option_strings[0]}: expected one argument")
        return parsed, extras
