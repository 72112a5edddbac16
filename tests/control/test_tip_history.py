"""Model level: the tracker-vs-model divergence compares a tracker sample with the model tip
commanded at the time the sample shows, not with the newest command."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.control.loop import TipHistory

PERIOD = 0.01  # s, a 100 Hz loop


def moving_tip(speed_mm_s: float, until_s: float) -> TipHistory:
    """Model tips along +x at ``speed_mm_s``, one per cycle from t = 0 to ``until_s``."""
    h = TipHistory(64)
    for t in np.arange(0.0, until_s + PERIOD / 2, PERIOD):
        h.add(float(t), np.array([speed_mm_s * t, 0.0, 300.0]))
    return h


def test_a_late_sample_of_a_moving_tip_is_not_divergence():
    # Tip at 100 mm/s; the sample shows it 50 ms ago (x = 45 mm at t = 0.45 s). The newest
    # command is 5 mm further on; the command of the sample's time is where the tip was.
    h = moving_tip(100.0, 0.5)
    sample = np.array([45.0, 0.0, 300.0])
    assert h.distance(0.5, sample, 0.05, lag_s=0.0, period_s=PERIOD) == pytest.approx(0.0)
    # Against the newest command alone it would be 5 mm.
    assert h.distance(0.5, sample, 0.0, lag_s=0.0, period_s=0.0) == pytest.approx(5.0)


def test_the_lag_allowance_covers_the_world_behind_the_command():
    # The world follows 30 ms behind the command, the sample is fresh.
    h = moving_tip(100.0, 0.5)
    sample = np.array([47.0, 0.0, 300.0])
    assert h.distance(0.5, sample, 0.0, lag_s=0.05, period_s=PERIOD) == pytest.approx(0.0)
    assert h.distance(0.5, sample, 0.0, lag_s=0.0, period_s=PERIOD) == pytest.approx(3.0)


def test_a_real_divergence_is_still_seen():
    # A tip 12 mm off the path (sideways) is 12 mm from every recent model tip.
    h = moving_tip(100.0, 0.5)
    sample = np.array([45.0, 12.0, 300.0])
    assert h.distance(0.5, sample, 0.05, lag_s=0.05, period_s=PERIOD) == pytest.approx(12.0)


def test_a_sample_older_than_the_history_falls_back_to_the_newest_tip():
    h = moving_tip(100.0, 0.5)
    sample = np.array([50.0, 0.0, 300.0])
    assert h.distance(0.5, sample, 10.0, lag_s=0.05, period_s=PERIOD) == pytest.approx(0.0)


def _numpy_distance(ts, tips, now_s, tip_mm, age_s, lag_s, period_s) -> float:
    """The numpy form TipHistory.distance had (the reference for the plain-float one)."""
    t, tip = np.array(ts), np.array(tips)
    t_sample = now_s - age_s
    sel = (t >= t_sample - lag_s) & (t <= t_sample + period_s)
    if not sel.any():
        sel = t == t.max()
    d = tip[sel] - tip_mm
    return float(np.sqrt((d * d).sum(axis=1)).min())


@settings(max_examples=300, deadline=None)
@given(
    st.integers(4, 40),
    st.integers(0, 120),
    st.lists(st.floats(-500, 500), min_size=3, max_size=3),
    st.one_of(st.floats(0.0, 0.6), st.just(np.inf)),
    st.floats(0.0, 0.1),
    st.floats(-1e3, 1e3),
    st.booleans(),
)
def test_distance_is_numpys_bit_for_bit(capacity, cycles, sample, age_s, lag_s, speed, nan_tip):
    h = TipHistory(capacity)  # times added in order: the newest-first window
    ts, tips = [-np.inf] * capacity, [[np.nan] * 3] * capacity
    rng = np.random.default_rng(cycles)
    for k in range(cycles):
        t = k * 0.004
        tip = [speed * t, 30.0 * np.sin(t) + rng.normal(0, 1e-3), 300.0 - 1e-7 * k]
        if nan_tip and k == cycles - 2:
            tip[1] = np.nan  # a model tip that failed
        h.add(t, np.array(tip))
        ts[k % capacity], tips[k % capacity] = t, tip
    now = max(cycles - 1, 0) * 0.004
    ref = _numpy_distance(ts, tips, now, np.array(sample), age_s, lag_s, 0.004)
    # The in-order pass (least squared distance, one root), the sample as an array and as the
    # loop passes it (a list), and the window-and-root scan it falls back on.
    t_sample = now - age_s
    for got in (
        h.distance(now, np.array(sample), age_s, lag_s, 0.004),
        h.distance(now, list(sample), age_s, lag_s, 0.004),
        h._distance_scan(t_sample - lag_s, t_sample + 0.004, *sample),
    ):
        assert (np.isnan(got) and np.isnan(ref)) or got == ref


def test_times_out_of_order_fall_back_to_the_full_scan():
    h = TipHistory(8)
    ts, tips = [-np.inf] * 8, [[np.nan] * 3] * 8
    for k, t in enumerate([0.0, 0.004, 0.008, 0.002, 0.012, 0.006]):
        tip = [t * 100.0, 1.0, 300.0]
        h.add(t, np.array(tip))
        ts[k], tips[k] = t, tip
    sample = np.array([0.5, 1.0, 300.0])
    for age in (0.0, 0.004, 0.007, 0.02):
        got = h.distance(0.012, sample, age, 0.003, 0.004)
        assert got == _numpy_distance(ts, tips, 0.012, sample, age, 0.003, 0.004)
