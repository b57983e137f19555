"""The command-line parser both CLIs use: every mistake is one line on stderr and exit status 2."""

from __future__ import annotations

import argparse
import sys
from typing import Any, NoReturn


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a bad option in one line, ``<prog>: error: <message><hint>``, and
    exits with status 2 (argparse's own also prints the usage).

    Args:
        hint: appended to every error, e.g. ``" (see --help)"``.
    """

    def __init__(self, *args: Any, hint: str = "", **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.hint = hint

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
