"""The cycle's plain-float arithmetic (control/loop/vectors.py) on hand-worked values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdcr_ctl.control.loop.vectors import actual_mm, added, floats, has_gap, target_counts


def test_gap_sum_and_flat_lists():
    assert not has_gap([1.0, -2.5, 0.0], [1.0, -2.5, -0.0])  # 0.0 - -0.0 == 0
    assert has_gap([1.0, 2.0, 3.0], [1.0, 2.0, 3.5])
    assert has_gap([1.0, math.nan, 3.0], [1.0, 2.0, 3.0])  # a NaN difference is a gap
    assert added([0.1, 1e16, -3.0], [0.2, 1.0, 3.0]) == [0.30000000000000004, 1e16, 0.0]
    assert floats(np.array([[1.0, 2.0], [3.0, 4.0]])) == [1.0, 2.0, 3.0, 4.0]
    assert floats((5.0, 6.0)) == [5.0, 6.0]


def test_targets_round_to_the_nearest_count_half_to_even():
    home = np.array([1000, -20, 0], dtype=np.int64)
    cpm = np.array([1238.6, 2.0, 4.0])
    # 1000 + 1 * 1238.6 = 2238.6 -> 2239; -20 + 0.25 * 2 = -19.5 -> -20 (even);
    # 0 + 0.625 * 4 = 2.5 -> 2 (even)
    assert target_counts([1.0, 0.25, 0.625], home, cpm) == [2239, -20, 2]
    assert target_counts([-1.0, 0.75, 0.875], home, cpm) == [-239, -18, 4]  # -18.5, 3.5
    for k, bad in enumerate((math.nan, math.inf, -math.inf)):
        q = [0.0, 0.0, 0.0]
        q[k] = bad
        with pytest.raises(ValueError, match=f"cable {k + 1} is not finite"):
            target_counts(q, home, cpm)


def test_actual_positions_in_mm_from_home():
    home = np.array([1000, -20, 2**40], dtype=np.int64)
    cpm = np.array([1238.6, 2.0, 4.0])
    got = actual_mm([2239, -19, 2**40 - 3], home, cpm)
    assert got == [1239 / 1238.6, 0.5, -0.75]  # one division each (integer difference first)
