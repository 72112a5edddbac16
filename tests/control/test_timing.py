"""Ticker: absolute deadlines, overrun counting without catch-up bursts."""

from __future__ import annotations

import time

from cdcr_ctl.control.timing import LatenessStats, Ticker


def test_deadlines_are_absolute_and_do_not_drift():
    t = Ticker(0.002)
    start = t.next_deadline
    for _ in range(50):
        t.wait()
        t.done()
    # 50 cycles later the schedule is exactly 50 periods on, whatever the lateness was.
    assert abs(t.next_deadline - (start + 50 * 0.002)) < 1e-9 or t.stats.skipped > 0
    assert t.stats.cycles == 50


def test_overrun_is_counted_and_missed_deadlines_are_skipped():
    t = Ticker(0.001)
    t.wait()
    time.sleep(0.0055)  # work takes 5.5 periods
    t.done()
    assert t.stats.overruns == 1
    assert t.stats.skipped >= 4
    assert t.next_deadline > time.monotonic() - 0.001


def test_stats_histogram_and_percentiles():
    s = LatenessStats()
    for us in [5, 5, 15, 150, 3000]:
        s.add(us * 1e-6)
    summ = s.summary()
    assert summ["cycles"] == 5
    assert summ["lateness_histogram"] == {
        "0-10us": 2,
        "10-20us": 1,
        "100-200us": 1,
        "2000-5000us": 1,
    }
    assert summ["lateness_max_us"] == 3000.0
    assert abs(s.percentiles_us((50,))["p50"] - 15.0) < 1e-9
