"""Convert an SB3 model directory (``model.zip`` + metadata) to the safe policy format.

    python -m capture_bench.agents.convert DIR... --trust-model

writes ``policy.pt`` and a declared ``metadata.json`` (`capture_bench.agents.policy_file`)
beside the ``.zip``, so the model then loads without unpickling anything. Converting unpickles
the ``.zip`` (and VecNormalize statistics): only for files you trust. Every directory is checked
(cheaply, before anything is unpickled) and loaded before any is written; every failure is one
line on stderr and exit status 2.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import yaml

from capture_bench.agents.policy_file import (
    POLICY_CLASSES,
    WEIGHTS_FILE,
    PolicyLoadError,
    policy_files,
    write_policy_files,
)
from capture_bench.agents.sb3_policy import find_metadata_file, load_trusted, read_metadata
from capture_bench.argparsing import OneLineParser

_CONVERTIBLE = (
    "convert takes a directory holding an SB3 .zip (from model.save) and a metadata.json naming "
    'its algorithm, e.g. {"algorithm": "PPO"}'
)


def _listing(directory: Path) -> str:
    names = sorted(p.name for p in directory.iterdir())
    return (", ".join(names[:6]) + (" ..." if len(names) > 6 else "")) or "nothing"


def _check_directory(directory: Path) -> None:
    if directory.is_dir():
        return
    if directory.exists():
        held_by = f" (the model directory may be {directory.parent})"
        raise PolicyLoadError(f"{directory}: a file, not a directory{held_by}; {_CONVERTIBLE}")
    if directory.name == "best" and directory.parent.is_dir():
        raise PolicyLoadError(
            f"{directory}: no such directory: the run has no best/ (train.py writes it only with "
            f"periodic validation, eval_freq > 0); its final model is {directory.parent}"
        )
    raise PolicyLoadError(f"{directory}: no such directory; {_CONVERTIBLE}")


def _metadata_entries(meta_file: Path) -> dict[str, Any]:
    """The entries of a metadata file, as read (the checks are `read_metadata`'s)."""
    kind = "JSON" if meta_file.suffix == ".json" else "YAML"
    expected = 'expected a mapping naming the algorithm, e.g. {"algorithm": "PPO"}'
    try:
        text = meta_file.read_text()
        data = json.loads(text) if kind == "JSON" else yaml.safe_load(text)
    except (OSError, ValueError, yaml.YAMLError) as exc:  # UnicodeDecodeError is a ValueError
        reason = " ".join(str(exc).split())
        reason = reason if len(reason) <= 100 else reason[:97] + "..."
        raise PolicyLoadError(f"{meta_file}: not valid {kind} ({reason}); {expected}") from None
    if not isinstance(data, dict):
        raise PolicyLoadError(f"{meta_file}: holds a {type(data).__name__}; {expected}")
    return data


def _check_plain_json(entries: dict[str, Any], meta_file: Path) -> None:
    """Refuse an entry ``metadata.json`` cannot hold (a YAML date, a NaN), naming it."""
    for key, value in entries.items():
        try:
            json.dumps(value, allow_nan=False)
        except (TypeError, ValueError):
            text = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
            raise PolicyLoadError(
                f"{meta_file}: entry {key!r} is {text}, which JSON cannot hold; valid: strings "
                "(quote a date), finite numbers, true, false, null, and lists or mappings of them"
            ) from None


def prepare_conversion(directory: Path) -> tuple[bytes, bytes]:
    """The ``policy.pt`` and ``metadata.json`` contents of the safe form of the SB3 model
    directory ``directory``; nothing is written (`write_policy_files` writes them).

    The directory's files are checked first (cheaply, before anything is unpickled); then the
    ``.zip`` (and VecNormalize statistics) are unpickled: call it only on files you trust.
    Existing metadata entries are kept; the declaration entries are added.

    Raises:
        PolicyLoadError: one line naming the file, what is wrong and what would be right.
    """
    directory = Path(directory)
    _check_directory(directory)
    meta_file = find_metadata_file(directory)
    if meta_file is None:
        raise PolicyLoadError(
            f"{directory}: no metadata file (found: {_listing(directory)}); {_CONVERTIBLE} "
            f"(valid: {', '.join(POLICY_CLASSES)})"
        )
    entries = _metadata_entries(meta_file)
    if not entries.get("model") and not any(directory.glob("*.zip")):
        raise PolicyLoadError(
            f"{directory}: no SB3 .zip to convert (found: {_listing(directory)}); {_CONVERTIBLE}"
        )
    weights = entries.get("weights")
    weights_file = directory / (weights if isinstance(weights, str) and weights else WEIGHTS_FILE)
    if "format" in entries and not weights_file.is_file():
        raise PolicyLoadError(
            f"{weights_file}: missing, though {meta_file.name} declares it; restore it, or, to "
            f"convert the .zip afresh, give {meta_file.name} only the model's own entries, "
            'e.g. {"algorithm": "PPO"}'
        )
    _check_plain_json(entries, meta_file)
    metadata = read_metadata(directory)
    loaded = load_trusted(metadata)
    entries.pop("vecnormalize", None)
    return policy_files(
        metadata.algorithm, loaded.policy, loaded.normalizer, entries, str(metadata.model_file)
    )


def convert(directory: Path) -> Path:
    """Write the safe form of the SB3 model directory ``directory`` beside its ``.zip``
    (`prepare_conversion`, then `write_policy_files`); returns the metadata file.

    This unpickles the ``.zip`` (and VecNormalize statistics): call it only on files you trust.
    """
    return write_policy_files(Path(directory), *prepare_conversion(directory))


def main(argv: list[str] | None = None) -> int:
    """``python -m capture_bench.agents.convert DIR... --trust-model``: convert SB3 models.

    Every directory is checked and loaded before any is written: a bad one writes nothing.
    """
    parser = OneLineParser(
        prog="python -m capture_bench.agents.convert",
        description="Convert an SB3 model directory (model.zip + metadata) to the safe form "
        "(policy.pt + declared metadata.json) that capture-bench loads without unpickling.",
    )
    parser.add_argument("directory", type=Path, nargs="+", help="SB3 model directories")
    parser.add_argument(
        "--trust-model",
        action="store_true",
        help="required: converting unpickles the .zip, which can run code; "
        "only for files you trust",
    )
    args = parser.parse_args(argv)
    if not args.trust_model:
        print(
            f"{parser.prog}: error: converting unpickles the SB3 .zip, which can run code; "
            "pass --trust-model if you trust where it came from",
            file=sys.stderr,
        )
        return 2
    try:
        prepared = [(directory, prepare_conversion(directory)) for directory in args.directory]
        for directory, (weights, metadata) in prepared:
            written = write_policy_files(directory, weights, metadata)
            print(f"{directory}: wrote {directory / WEIGHTS_FILE} and {written}")
    except PolicyLoadError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(
            f"{parser.prog}: error: {exc.filename or 'model directory'}: {exc.strerror or exc}; "
            "convert must read the model directory and write policy.pt and metadata.json into it",
            file=sys.stderr,
        )
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
