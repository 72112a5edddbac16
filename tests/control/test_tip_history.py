"""Model level: the tracker-vs-model divergence compares a tracker sample with the model tip
commanded at the time the sample shows, not with the newest command."""

from __future__ import annotations

import numpy as np
import pytest

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


def test_times_out_of_order_take_every_entry_in_the_window():
    # Tips at x = 100 t along the path, the sample at x = 0.5 mm: its distance to the tip of
    # time t is |100 t - 0.5| mm. The time 0.006 comes after 0.012: a newest-first look that
    # stopped at the first entry older than the window would miss it.
    h = TipHistory(8)
    for t in [0.0, 0.004, 0.008, 0.002, 0.012, 0.006]:
        h.add(t, [t * 100.0, 1.0, 300.0])
    sample = np.array([0.5, 1.0, 300.0])
    # (age s, nearest tip's time): windows [0.012 - age - 0.003, 0.012 - age + 0.004]
    for age, t_near in ((0.0, 0.012), (0.004, 0.006), (0.007, 0.004), (0.02, 0.012)):
        got = h.distance(0.012, sample, age, 0.003, 0.004)
        assert got == pytest.approx(abs(100.0 * t_near - 0.5), abs=1e-12), age


def test_the_least_of_several_distances_and_a_failed_tip():
    h = TipHistory(4)
    h.add(0.0, [3.0, 4.0, 0.0])  # 5 mm from the origin
    h.add(0.01, [0.0, 0.0, 2.0])  # 2 mm
    h.add(0.02, [1.0, 2.0, 2.0])  # 3 mm
    assert h.distance(0.02, [0.0, 0.0, 0.0], 0.0, 0.05, 0.0) == 2.0  # sqrt(4): exact
    assert h.distance(0.02, [0.0, 0.0, 0.0], 0.0, 0.005, 0.0) == 3.0  # the newest alone
    # the never-written entry (t = -inf, NaN tip) is in a window open to -inf
    assert np.isnan(h.distance(0.02, [0.0, 0.0, 0.0], np.inf, 0.0, 0.0))
    h.add(0.03, [np.nan, 0.0, 0.0])  # a model tip that failed: no distance
    assert np.isnan(h.distance(0.03, [0.0, 0.0, 0.0], 0.0, 0.05, 0.0))
