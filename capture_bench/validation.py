"""One validator for every configuration file: scenarios, suites and algorithm hyper-parameters.

A file is read once (`read_mapping`: missing file, invalid YAML, not a mapping), then checked
against a schema, a mapping of key to `Rule` (or to a nested schema) by
`check_mapping`. Every message has one shape, names the file and the key (dotted for nested
keys), the bad value and what would be valid::

    configs/scenarios/x.yaml: key 'camera.noise_px': -1 is not valid; expected a number in [0, 100]
    configs/scenarios/x.yaml: unknown key 'camera.noise_pix'; valid keys: position, look_at, ...
    configs/suites/s.yaml: missing key 'episodes' (expected a whole number >= 1)

A message stays one short line whatever the file holds: a value is shown by `shown` (a
bounded repr, however large or deeply nested the value, e.g. a YAML alias bomb), a file larger
than `MAX_FILE_BYTES` is refused before it is read, and a key given twice in one mapping is
refused with its line (YAML would otherwise keep the last silently).

The error type is the caller's (``ConfigError`` for scenarios and algorithms, ``SuiteError`` for
suites), so each CLI keeps its own catch.
"""

from __future__ import annotations

import math
import re
import reprlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml


class ConfigError(ValueError):
    """A configuration file or value is invalid; the message says where and what is valid."""


#: What reading YAML raises on text that is not valid YAML data: besides ``YAMLError``, the safe
#: constructors raise ValueError, KeyError, AttributeError or TypeError on a tagged, date-like or
#: unhashable scalar that does not parse (``!!bool maybe``, ``2001-13-01``, ``? [a]: 1``), the
#: parser RecursionError on deep nesting; bytes that are not UTF-8 raise UnicodeDecodeError.
YAML_ERRORS = (yaml.YAMLError, ValueError, KeyError, AttributeError, TypeError, RecursionError)

#: The largest configuration file read, bytes (1 MiB; the shipped ones are a few kB). The size is
#: checked before the file is read or parsed.
MAX_FILE_BYTES = 1 << 20

#: A name that becomes part of an env ID and of file names (a scenario's ``name``): lowercase
#: letters, digits and ``_``, starting with a letter, at most 64 characters.
IDENTIFIER = re.compile(r"[a-z][a-z0-9_]{0,63}")
IDENTIFIER_TEXT = (
    "a name of lowercase letters, digits and _ starting with a letter, at most 64 characters, "
    "like grasp_rendered"
)

#: The longest `shown` text, characters.
SHOWN_CHARS = 80
_SHORT = reprlib.Repr()
_SHORT.maxlevel = 3
_SHORT.maxtuple = _SHORT.maxlist = _SHORT.maxarray = _SHORT.maxdict = 6
_SHORT.maxset = _SHORT.maxfrozenset = _SHORT.maxdeque = 6
_SHORT.maxstring = 60
_SHORT.maxlong = 40
_SHORT.maxother = 60


def shown(value: Any) -> str:
    """``repr(value)`` for a message: at most `SHOWN_CHARS` characters (``...`` where cut),
    computed in a bounded time however long, large or deeply nested the value is (a YAML alias
    bomb nests references that a full repr would expand exponentially)."""
    text = _SHORT.repr(value)
    return text if len(text) <= SHOWN_CHARS else text[: SHOWN_CHARS - 3] + "..."


@dataclass(frozen=True)
class Rule:
    """What one key accepts.

    ``kind``: ``int``, ``float`` (finite numbers in [low, high], ``low`` exclusive unless
    ``low_inclusive``), ``bool``, ``string``, ``identifier`` (a string matching
    `IDENTIFIER`), ``choice`` (one of ``choices``), ``numbers`` (a list
    of ``length`` numbers of ``item`` kind; a 2-float list is a [low, high] range), ``names`` (a
    non-empty list of non-empty strings, or one of ``choices`` as a whole), ``schedule`` (a number
    > 0 or ``lin_<number>``), ``float_or_auto`` (a number, ``auto`` or ``auto_<number>``),
    ``optional_float`` (a number or null), ``layers`` (a list of layer widths, or a mapping of
    ``choices`` to such lists), ``mapping`` (checked by a nested schema), ``weights`` (a
    non-empty mapping of names to numbers > 0), ``choice_per_name`` (one of ``choices``, or a
    non-empty mapping of names to them).
    """

    kind: str
    low: float = -math.inf
    high: float = math.inf
    low_inclusive: bool = True
    choices: tuple[str, ...] = ()
    length: int = 0
    item: str = "float"

    def describe(self) -> str:
        """What the rule accepts, in words."""
        kind = self.kind
        if kind == "choice":
            return "one of " + ", ".join(self.choices)
        if kind in ("int", "float", "optional_float"):
            text = {"int": "a whole number", "float": "a number", "optional_float": "a number"}[
                kind
            ]
            return text + self._range() + (" or null" if kind == "optional_float" else "")
        if kind == "numbers":
            what = "whole numbers" if self.item == "int" else "numbers"
            order = (
                " [low, high] with low <= high" if self.length == 2 and self.item == "float" else ""
            )
            each = f", each{self._range()}" if self._range() else ""
            return f"a list of {self.length} {what}{order}{each}"
        if kind == "names":
            also = f", or {' or '.join(map(repr, self.choices))}" if self.choices else ""
            return "a non-empty list of names" + also
        if kind == "choice_per_name":
            other = self.choices[1 % len(self.choices)]
            return (
                f"one of {', '.join(self.choices)}, or a mapping of scenario names (and "
                f"default) to them, like {{default: {other}, grasp: {self.choices[0]}}}"
            )
        if kind == "layers":
            keys = ", ".join(f"{k}: [...]" for k in self.choices)
            return f"a list of layer widths like [64, 64] or a mapping {{{keys}}}"
        return {
            "bool": "true or false",
            "string": "a string",
            "identifier": IDENTIFIER_TEXT,
            "schedule": "a number > 0 or 'lin_<number>' (linear decay to 0)",
            "float_or_auto": "a number, 'auto' or 'auto_<number>'",
            "mapping": "a mapping",
            "weights": "a mapping of names to numbers > 0, like {grasp: 4}",
        }[kind]

    def _range(self) -> str:
        low = math.isfinite(self.low)
        high = math.isfinite(self.high)
        if low and high:
            return f" in {'[' if self.low_inclusive else '('}{self.low:g}, {self.high:g}]"
        if low:
            return f" {'>=' if self.low_inclusive else '>'} {self.low:g}"
        if high:
            return f" <= {self.high:g}"
        return ""

    def check(self, value: Any, where: str, error: type[ValueError] = ConfigError) -> Any:
        """``value`` in canonical form (ints as int, numbers as float, lists as tuples of
        ``numbers``), or ``error`` saying ``where: value is not valid; expected ...``."""
        ok, canonical = _CHECKS[self.kind](self, value)
        if not ok:
            raise error(f"{where}: {shown(value)} is not valid; expected {self.describe()}")
        return canonical


def _number(value: Any) -> float | None:
    """The value as a finite float, or None (bools are not numbers; YAML reads 3e-4 as a string,
    which is accepted as the number it is)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        return None
    try:
        number = float(value)
    except (ValueError, OverflowError):
        return None
    return number if math.isfinite(number) else None


def _in_range(rule: Rule, number: float) -> bool:
    above = number >= rule.low if rule.low_inclusive else number > rule.low
    return above and number <= rule.high


def _check_int(rule: Rule, value: Any) -> tuple[bool, Any]:
    if isinstance(value, int) and not isinstance(value, bool):  # exact, however large
        return _in_range(rule, value), value
    number = _number(value)
    if number is None or not number.is_integer() or not _in_range(rule, number):
        return False, None
    return True, int(number)


def _check_float(rule: Rule, value: Any) -> tuple[bool, Any]:
    number = _number(value)
    return (number is not None and _in_range(rule, number)), number


def _check_optional_float(rule: Rule, value: Any) -> tuple[bool, Any]:
    return (True, None) if value is None else _check_float(rule, value)


def _check_numbers(rule: Rule, value: Any) -> tuple[bool, Any]:
    if not isinstance(value, (list, tuple)) or len(value) != rule.length:
        return False, None
    items = []
    item = Rule(rule.item, rule.low, rule.high, rule.low_inclusive)  # each item in the range
    for v in value:
        ok, number = _CHECKS[rule.item](item, v)
        if not ok:
            return False, None
        items.append(number)
    if rule.length == 2 and rule.item == "float" and items[0] > items[1]:
        return False, None
    return True, tuple(items)


def _check_names(rule: Rule, value: Any) -> tuple[bool, Any]:
    if isinstance(value, str) and value in rule.choices:
        return True, (value,)
    ok = isinstance(value, list) and value and all(isinstance(v, str) and v for v in value)
    return bool(ok), tuple(dict.fromkeys(value)) if ok else None


def _check_weights(rule: Rule, value: Any) -> tuple[bool, Any]:
    if not isinstance(value, dict) or not value:
        return False, None
    numbers = {k: _number(v) for k, v in value.items()}
    ok = all(isinstance(k, str) and k and n is not None and n > 0 for k, n in numbers.items())
    return ok, numbers if ok else None


def _check_choice_per_name(rule: Rule, value: Any) -> tuple[bool, Any]:
    if isinstance(value, str):
        return value in rule.choices, value
    ok = (
        isinstance(value, dict)
        and bool(value)
        and all(isinstance(k, str) and k and v in rule.choices for k, v in value.items())
    )
    return ok, dict(value) if ok else None


def _check_prefixed(rule: Rule, value: Any) -> tuple[bool, Any]:
    """``schedule`` (a number > 0 or lin_<number > 0>) and ``float_or_auto``."""
    if isinstance(value, str) and _number(value) is None:
        prefix = "lin_" if rule.kind == "schedule" else "auto"
        rest = value[len(prefix) :].lstrip("_")
        if not value.startswith(prefix) or (rest and _number(rest) is None):
            return False, None
        if rule.kind == "schedule" and (not rest or float(rest) <= 0):
            return False, None
        return True, value
    number = _number(value)
    if number is None or (rule.kind == "schedule" and number <= 0):
        return False, None
    return True, number


def _check_layers(rule: Rule, value: Any) -> tuple[bool, Any]:
    def widths(v: Any) -> bool:
        return isinstance(v, list) and all(
            isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in v
        )

    if widths(value):
        return True, value
    ok = (
        isinstance(value, dict)
        and bool(value)
        and all(k in rule.choices and widths(v) for k, v in value.items())
    )
    return ok, value


_CHECKS = {
    "int": _check_int,
    "float": _check_float,
    "optional_float": _check_optional_float,
    "bool": lambda rule, v: (isinstance(v, bool), v),
    "string": lambda rule, v: (isinstance(v, str), v),
    "identifier": lambda rule, v: (isinstance(v, str) and IDENTIFIER.fullmatch(v) is not None, v),
    "choice": lambda rule, v: (isinstance(v, str) and v in rule.choices, v),
    "numbers": _check_numbers,
    "names": _check_names,
    "schedule": _check_prefixed,
    "float_or_auto": _check_prefixed,
    "layers": _check_layers,
    "mapping": lambda rule, v: (isinstance(v, dict), v),
    "weights": _check_weights,
    "choice_per_name": _check_choice_per_name,
}

#: A schema: key -> Rule, or key -> nested schema (a mapping under that key).
Schema = Mapping[str, "Rule | Schema"]


def is_file(path: Path) -> bool:
    """``path.is_file()``, False where the path cannot even be looked at (a name too long, no
    permission on a parent) instead of an OSError."""
    try:
        return path.is_file()
    except OSError:
        return False


class _DuplicateKey(Exception):
    """A key given twice in one YAML mapping: the key and the lines (1-based) of both."""

    def __init__(self, key: Any, first_line: int, line: int) -> None:
        super().__init__(key, first_line, line)
        self.key, self.first_line, self.line = key, first_line, line


class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, except that a key given twice in one mapping raises (the safe loader
    keeps the last value silently). Keys that YAML reads as equal count as the same key (``1``
    and ``true``); a key that a merge (``<<: *anchor``) brings in may be given again, as the
    merge's override."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, yaml.Node] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.setdefault(key, key_node)
                except TypeError:  # unhashable: the base constructor refuses it
                    continue
                if first is not key_node:
                    raise _DuplicateKey(
                        key, first.start_mark.line + 1, key_node.start_mark.line + 1
                    )
        return super().construct_mapping(node, deep=deep)


def _one_line(text: str, limit: int = 200) -> str:
    """``text`` on one line, at most ``limit`` characters."""
    line = " ".join(text.split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


def _size_error(path: Path, size: int, error: type[ValueError]) -> ValueError:
    return error(
        f"{path}: the file's size, {size} bytes, is not valid; expected at most {MAX_FILE_BYTES} "
        f"bytes ({MAX_FILE_BYTES // (1 << 20)} MiB) for a configuration file"
    )


def read_mapping(
    path: Path, what: str, error: type[ValueError] = ConfigError
) -> tuple[dict[str, Any], bytes]:
    """The YAML mapping in ``path`` and the file's bytes (for provenance hashes).

    Raises ``error`` naming the file: it cannot be read, it is larger than
    `MAX_FILE_BYTES` (checked before reading), invalid YAML (the parser's message), a key
    given twice in one mapping (the key and both lines), or not a mapping (``what`` says of what:
    "scenario keys", "hyper-parameters", ...).
    """
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise _size_error(path, size, error)
        with path.open("rb") as file:
            raw = file.read(MAX_FILE_BYTES + 1)
    except OSError as exc:  # missing, a folder, no permission, a name too long
        raise error(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if len(raw) > MAX_FILE_BYTES:  # it grew after the size was checked
        raise _size_error(path, len(raw), error)
    try:
        data = yaml.load(raw, Loader=UniqueKeyLoader)  # a SafeLoader: plain data only
    except _DuplicateKey as exc:
        raise error(
            f"{path}: key {shown(exc.key)} is given twice in one mapping (lines "
            f"{exc.first_line} and {exc.line}); expected each key once"
        ) from None
    except YAML_ERRORS as exc:
        first = _one_line(str(exc)) or type(exc).__name__
        raise error(f"{path}: invalid YAML ({first})") from None
    if not isinstance(data, dict):
        raise error(f"{path}: expected a mapping of {what}, got {type(data).__name__}")
    return data, raw


def check_mapping(
    data: Any,
    schema: Schema,
    source: str,
    *,
    error: type[ValueError] = ConfigError,
    prefix: str = "",
    required: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """``data`` checked against ``schema``: every key known, every value valid (nested schemas
    recursively); returns the canonical values (keys absent from ``data`` stay absent).

    Args:
        data: the mapping read from the file.
        schema: key -> `Rule` or nested schema.
        source: the file (or ``<override>``), first in every message.
        error: the exception type raised.
        prefix: the dotted path of ``data`` inside the file (``"camera."``), for messages.
        required: keys that must be present -> what they hold, for the message.
    """
    if not isinstance(data, dict):
        where = f"key {shown(prefix[:-1])}" if prefix else "the file"
        raise error(f"{source}: {where} must be a mapping, got {shown(data)}")
    unknown = [key for key in data if key not in schema]
    if unknown:
        raise error(
            f"{source}: unknown key {shown(prefix + str(unknown[0]))}; valid keys: "
            + ", ".join(schema)
        )
    for key, what in (required or {}).items():
        if key not in data:
            raise error(f"{source}: missing key {shown(prefix + key)} ({what})")
    out: dict[str, Any] = {}
    for key, value in data.items():
        rule = schema[key]
        if isinstance(rule, Rule):
            out[key] = rule.check(value, f"{source}: key {shown(prefix + key)}", error)
        else:
            out[key] = check_mapping(value, rule, source, error=error, prefix=f"{prefix}{key}.")
    return out
