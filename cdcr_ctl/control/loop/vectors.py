"""The cycle's per-cable arithmetic on Python floats: the same IEEE operations numpy does on the
cycle's (K,) arrays, without numpy's per-call overhead (~1 us a call on three values, and a
cycle made a dozen such calls).

Each function states the numpy expression it stands for; ``tests/control/test_loop_vectors.py``
holds them equal bit for bit (and falls back on numpy where Python would differ: a target that is
not finite). Units: mm, counts, counts/mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def floats(a: Any) -> list[Any]:
    """``np.ravel(a).tolist()``: the values of an array (or sequence) as a flat Python list."""
    if isinstance(a, np.ndarray):
        return a.ravel().tolist()
    return np.ravel(a).tolist()


def has_gap(target: Sequence[float], offset: Sequence[float]) -> bool:
    """``(target - offset).any()``: some difference non-zero (NaN counts, as in numpy)."""
    for t, o in zip(target, offset, strict=True):  # noqa: SIM110 - no generator per cycle
        if t - o != 0.0:
            return True
    return False


def added(a: Sequence[float], b: Sequence[float]) -> list[float]:
    """``a + b`` element by element (float64 addition, as numpy's)."""
    return [x + y for x, y in zip(a, b, strict=True)]


def target_counts(q_mm: Sequence[float], home: np.ndarray, counts_per_mm: Any) -> list[int]:
    """``np.rint(home + q_mm * counts_per_mm).astype(np.int64).tolist()``.

    Python's ``round`` of a float rounds half to even as ``np.rint`` does, and an int plus a
    float converts the int to float64 first as numpy does for int64 + float64. A value that is
    not finite (or arrays of other shapes) goes through numpy, as before.
    """
    try:
        return [
            round(h + q * c)
            for h, q, c in zip(home.tolist(), q_mm, counts_per_mm.tolist(), strict=True)
        ]
    except (AttributeError, TypeError, ValueError, OverflowError):
        q = np.asarray(q_mm, dtype=float)
        return np.rint(home + q * counts_per_mm).astype(np.int64).tolist()


def actual_mm(positions: Sequence[int], home: np.ndarray, counts_per_mm: Any) -> list[float]:
    """``((np.array(positions) - home) / counts_per_mm).tolist()``: counts from home in mm
    (integer difference, then one float64 division; exact below 2**53 counts)."""
    try:
        return [
            (p - h) / c
            for p, h, c in zip(positions, home.tolist(), counts_per_mm.tolist(), strict=True)
        ]
    except (AttributeError, TypeError, ValueError, ZeroDivisionError, OverflowError):
        return ((np.array(positions) - home) / counts_per_mm).tolist()
