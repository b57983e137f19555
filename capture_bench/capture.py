"""The capture test of eq. 20, applied over a whole control step.

Eq. 20 declares a capture when ``|X_E - X_T| < epsilon`` component-wise. Testing only at the ends
of a step would let a fast pass through the tolerance box go unseen, so the test is applied to
the whole step: the end-effector and the target are taken to move linearly between the two ends
of the step (the step is short: at most 0.0206 rad on the pitch joints, whose arc sags from its
chord by < 0.05 mm), and the relative vector ``d(s) = d0 + s (d1 - d0)``, ``s in [0, 1]``, is
tested exactly.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike


def first_entry_fraction(d0: ArrayLike, d1: ArrayLike, tolerance: ArrayLike) -> float | None:
    """Earliest fraction s of the step at which ``|d0 + s (d1 - d0)| < tolerance`` in every
    component, or None if the relative vector never enters the tolerance box.

    Args:
        d0: X_E - X_T at the start of the step, m, shape (3,).
        d1: X_E - X_T at the end of the step, m, shape (3,).
        tolerance: epsilon, m, shape (3,) (or a scalar).

    Returns:
        s in [0, 1], or None. Each component is inside its box on an open interval of s; the box
        is entered where all intervals overlap.
    """
    lo, hi = 0.0, 1.0
    for a, b, e in zip(_floats(d0), _floats(d1), _tolerances(tolerance)):
        slope = b - a
        if slope == 0.0:
            if abs(a) >= e:
                return None
            continue
        s_a, s_b = (-e - a) / slope, (e - a) / slope
        lo = max(lo, min(s_a, s_b))
        hi = min(hi, max(s_a, s_b))
        if lo >= hi:
            # The intervals are open, so touching ends (lo == hi) is not an entry.
            return None
    return lo


def within_tolerance(d: ArrayLike, tolerance: ArrayLike) -> bool:
    """Eq. 20 at one instant: ``|d| < epsilon`` in every component."""
    return all(abs(c) < e for c, e in zip(_floats(d), _tolerances(tolerance)))


def segment_length(a: ArrayLike, b: ArrayLike) -> float:
    """Euclidean distance between two points, m."""
    return math.dist(_floats(a), _floats(b))


def _floats(v: ArrayLike) -> list[float]:
    return v.tolist() if isinstance(v, np.ndarray) else [float(x) for x in v]  # type: ignore[union-attr]


def _tolerances(tolerance: ArrayLike) -> list[float]:
    """epsilon as three floats (a scalar applies to every component)."""
    if isinstance(tolerance, (int, float)):
        return [float(tolerance)] * 3
    return _floats(tolerance)
