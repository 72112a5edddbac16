"""The cycle's plain-float arithmetic (control/loop/vectors.py) against the numpy expressions it
stands for, bit for bit."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.control.loop.vectors import actual_mm, added, floats, has_gap, target_counts

mm = st.floats(-1e4, 1e4, allow_nan=False)
any_float = st.floats(allow_nan=True, allow_infinity=True)
counts = st.integers(-(2**31), 2**31 - 1)
cpm = st.floats(1e-3, 1e5)


def same_bits(a: list[float], b: list[float]) -> bool:
    return np.array(a, dtype=float).tobytes() == np.array(b, dtype=float).tobytes()


@settings(max_examples=300, deadline=None)
@given(st.lists(any_float, min_size=3, max_size=3), st.lists(any_float, min_size=3, max_size=3))
def test_gap_and_sum_are_numpys(a, b):
    x, y = np.array(a), np.array(b)
    with np.errstate(all="ignore"):
        assert has_gap(a, b) == bool((x - y).any())
        assert same_bits(added(a, b), (x + y).tolist())
    assert same_bits(floats(x), a) and same_bits(floats(a), a)


@settings(max_examples=500, deadline=None)
@given(
    st.lists(mm, min_size=3, max_size=3),
    st.lists(counts, min_size=3, max_size=3),
    st.lists(cpm, min_size=3, max_size=3),
)
def test_targets_and_actual_are_numpys(q, home, c):
    h, k = np.array(home, dtype=np.int64), np.array(c)
    want = np.rint(h + np.array(q) * k).astype(np.int64).tolist()
    assert target_counts(q, h, k) == want
    # half-way values round to even, as np.rint
    halves = [(v + 0.5 - hh) / kk for v, hh, kk in zip(home, home, c, strict=True)]
    want = np.rint(h + np.array(halves) * k).astype(np.int64).tolist()
    assert target_counts(halves, h, k) == want
    pos = [hh + int(v * kk) for hh, v, kk in zip(home, q, c, strict=True)]
    assert same_bits(actual_mm(pos, h, k), ((np.array(pos) - h) / k).tolist())


def test_what_python_cannot_round_goes_through_numpy():
    h, k = np.array([0, 0, 0], dtype=np.int64), np.array([1.0, 1.0, 1.0])
    with np.errstate(all="ignore"):
        want = np.rint(h + np.array([np.nan, 1.0, np.inf]) * k).astype(np.int64).tolist()
        assert target_counts([np.nan, 1.0, np.inf], h, k) == want
    # a scalar scale (no per-cable list) too
    assert target_counts([1.0, 2.0, 3.0], h, 2.0) == [2, 4, 6]
    assert actual_mm([2, 4, 6], h, 2.0) == [1.0, 2.0, 3.0]
