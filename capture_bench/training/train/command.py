"""``train.py``'s command (installed as ``capture-bench-train``, also ``python -m capture_bench
train``): `main` trains one run with the given options. It is
`capture_bench.training.common.run.main`, kept in `capture_bench.training.common` because the
sweep's tasks and ``curves --train`` train their runs through the same function."""

from __future__ import annotations

from capture_bench.training.common.run import main

__all__ = ["main"]
