"""Synthetic episode records for the tests of the ranking and the report."""

from __future__ import annotations

import dataclasses
import math

from capture_bench.evaluation.running.rollout import EpisodeRecord


def record(agent: str, scenario: str, seed: int, ratio: float | None) -> EpisodeRecord:
    """An episode captured at ``ratio`` x a 1 s physical limit, or timed out (``ratio`` None);
    every other column NaN."""
    values: dict = {
        f.name: math.nan
        for f in dataclasses.fields(EpisodeRecord)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    }
    captured = ratio is not None
    values.update(
        agent=agent,
        scenario=scenario,
        seed=seed,
        outcome="captured" if captured else "failed",
        failure="" if captured else "timeout",
        capture_time=ratio if captured else math.nan,
        end_time=ratio if captured else 10.0,
        physical_limit_time=1.0,
        ratio=ratio if captured else math.nan,
        steps=10,
        wall_clock_s=0.0,
    )
    return EpisodeRecord(**values)
