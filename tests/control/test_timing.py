"""Ticker: absolute deadlines, overrun counting without catch-up bursts."""

from __future__ import annotations

import time

import numpy as np

from cdcr_ctl.control.timing import (
    QUIET_GUARD_S,
    QUIET_STALE_S,
    BetweenCycles,
    LatenessStats,
    Ticker,
    percentiles,
)


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


def test_histogram_bins_are_numpy_searchsorted_bins():
    from cdcr_ctl.control.timing import LATENESS_EDGES_US

    s = LatenessStats()
    values = [0.0, 9.99, 10.0, 10.01, 199.9, 200.0, 99_999.0, 100_000.0, 5e6]
    for us in values:
        s.add(us * 1e-6)
    want = np.zeros(len(LATENESS_EDGES_US) - 1, int)
    for us in values:
        i = int(np.searchsorted(LATENESS_EDGES_US, us * 1e-6 * 1e6, side="right")) - 1
        want[min(max(i, 0), len(want) - 1)] += 1
    assert s.histogram.tolist() == want.tolist()


def test_reset_stats_starts_afresh_and_keeps_the_schedule():
    t = Ticker(0.001)
    for _ in range(5):
        t.wait()
        t.done()
    deadline = t.next_deadline
    old = t.reset_stats()
    assert old.cycles == 5 and t.stats.cycles == 0 and t.stats.overruns == 0
    assert t.next_deadline == deadline


def test_percentiles_equal_numpy_percentile_linear():
    # The partition-based percentiles (status's lateness p50/p99/p99.9) against numpy's own, on
    # sizes from one sample to the full reservoir, with ties. Both interpolate linearly between
    # the same two order statistics; they may differ only in the last bits of that lerp, so the
    # tolerance is a few ulps of the largest value.
    rng = np.random.default_rng(7)
    qs = (0.0, 50.0, 99.0, 99.9, 100.0)
    for n in (1, 2, 3, 10, 999, 65536):
        for a in (rng.exponential(50.0, n), np.round(rng.exponential(50.0, n))):
            got = np.array(percentiles(a, qs))
            want = np.percentile(a, qs)
            tol = 8 * np.spacing(max(float(np.abs(a).max()), 1.0))
            assert np.all(np.abs(got - want) <= tol), (n, got, want)


def test_between_cycles_until_the_guard_before_the_wake_up_and_when_stale():
    now = [100.0]
    b = BetweenCycles(clock=lambda: now[0])
    assert b()  # before the loop's first cycle
    b.mark(101.0, 0.5)  # next wake-up at 100.5 s: quiet until 100.5 s less the guard
    assert b()
    now[0] = 100.5 - QUIET_GUARD_S  # from there until the loop's next cycle ends: not quiet
    assert not b()
    now[0] = 100.5 - QUIET_GUARD_S + QUIET_STALE_S / 2
    assert not b()
    now[0] = 100.5 - QUIET_GUARD_S + 2 * QUIET_STALE_S  # no cycle ended for too long
    assert b()
    b.mark(now[0] + 1.0, 0.0)
    assert b()
    b.clear()
    assert b()
