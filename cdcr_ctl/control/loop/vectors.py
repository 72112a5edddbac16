"""The cycle's per-cable arithmetic on Python floats (lists of K values): float64 operations
without numpy's per-call overhead (~1 us a call on three values, and a cycle made a dozen such
calls). Units: mm, counts, counts/mm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np


def floats(a: Any) -> list[Any]:
    """The values of an array (or sequence) as a flat Python list."""
    if isinstance(a, np.ndarray):
        return a.ravel().tolist()
    return np.ravel(a).tolist()


def has_gap(target: Sequence[float], offset: Sequence[float]) -> bool:
    """Some ``target - offset`` non-zero (a NaN difference counts)."""
    for t, o in zip(target, offset, strict=True):  # noqa: SIM110 - no generator per cycle
        if t - o != 0.0:
            return True
    return False


def added(a: Sequence[float], b: Sequence[float]) -> list[float]:
    """``a + b`` element by element (float64 addition)."""
    return [x + y for x, y in zip(a, b, strict=True)]


def target_counts(q_mm: Sequence[float], home: np.ndarray, counts_per_mm: np.ndarray) -> list[int]:
    """Target positions (counts): ``home + q_mm * counts_per_mm`` per cable, rounded to the
    nearest count, half to even (Python's ``round`` of a float; the int home converted to float
    first). A target that is not finite raises ValueError naming the cable (the supervisor
    halts on such a command before it gets here)."""
    out = []
    for k, (h, q, c) in enumerate(zip(home.tolist(), q_mm, counts_per_mm.tolist(), strict=True)):
        x = h + q * c
        if not math.isfinite(x):
            raise ValueError(f"target of cable {k + 1} is not finite: {h} + {q} mm * {c} counts/mm")
        out.append(round(x))
    return out


def actual_mm(positions: Sequence[int], home: np.ndarray, counts_per_mm: np.ndarray) -> list[float]:
    """Positions from home in mm: ``(position - home) / counts_per_mm`` per cable (an integer
    difference, then one float64 division; exact below 2**53 counts)."""
    return [
        (p - h) / c
        for p, h, c in zip(positions, home.tolist(), counts_per_mm.tolist(), strict=True)
    ]
