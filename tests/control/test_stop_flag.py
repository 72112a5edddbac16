"""The loop's stop flag and its stall accounting (issue #21): a stop set with no lock is acted on
in the next cycle and recorded in the row's event; a stalled cycle says so in the next row and
in the counters."""

from __future__ import annotations

import time

import numpy as np
from test_loop import ListSink, Ramp, make_loop, wait_until

from cdcr_ctl.control.loop import OPERATOR_STOP
from cdcr_ctl.control.supervisor import Reaction


def test_stop_flag_acts_in_the_next_cycle_while_the_command_lock_is_held():
    loop, drives, _ten, _sup = make_loop()
    loop.start()
    try:
        sink = ListSink()
        run = loop.follow(Ramp(0.5, 5.0), "r", None, sink)
        assert wait_until(lambda: loop.current_run is run)
        # A planner holding the loop's own command lock must not hold the stop up.
        with loop._lock:
            seq = loop.stop_flag.request(Reaction.QUICK_STOP)
            c0 = loop.counters.cycles
            assert wait_until(lambda: loop.stop_flag.acted_cycle(seq) is not None)
        acted = loop.stop_flag.acted_cycle(seq)
        assert acted - c0 <= 2  # counted in cycles: independent of the machine's speed
        assert drives.quick_stops == 1
        assert wait_until(lambda: run.state == "stopped")
        events = [r["event"] for r in sink.rows]
        assert any(OPERATOR_STOP in e for e in events)
    finally:
        loop.stop()


class StallingSink(ListSink):
    """A sink whose write blocks once for ``stall_s`` (a stall inside one cycle)."""

    def __init__(self, stall_s: float) -> None:
        super().__init__()
        self.stall_s = stall_s
        self.stalled_at: int | None = None

    def write(self, row):
        if self.stalled_at is None and len(self.rows) == 20:
            self.stalled_at = row["cycle"]
            time.sleep(self.stall_s)
        return super().write(row)


def test_a_stalled_cycle_says_so_in_the_next_row_and_the_counters():
    loop, _drives, _ten, _sup = make_loop()
    period = loop.cfg.period_s
    loop.start()
    try:
        sink = StallingSink(stall_s=0.05)  # 25 periods of 2 ms
        loop.follow(Ramp(0.1, 2.0), "r", None, sink)
        assert wait_until(lambda: len(sink.rows) > 40)
        after = next(r for r in sink.rows if r["cycle"] == sink.stalled_at + 1)
        missed = loop.counters.missed_cycles
        assert missed >= 0.05 / period - 2  # the stall's deadlines, whatever else was late
        assert loop.counters.long_cycles >= 1
        assert "cycles missed" in after["event"]
        n = int(after["event"].split("late: ")[1].split()[0])
        # The row's lateness counts from the first missed deadline.
        assert after["lateness_us"] >= n * period * 1e6
        assert np.isfinite(after["t_s"])
    finally:
        loop.stop()


def _flagged(rows, pattern: str) -> int:
    """Sum of N in ``late: N cycles missed`` (or count of ``long:`` notes) over ``rows``."""
    total = 0
    for r in rows:
        ev = r["event"]
        if pattern == "late" and "late: " in ev:
            total += int(ev.split("late: ")[1].split()[0])
        elif pattern == "long" and "long: previous cycle" in ev:
            total += 1
    return total


def test_the_loops_counters_and_the_rows_agree():
    """Issue #21: missed deadlines and long cycles the loop's global counters add while a run is
    logged equal what its rows report, and every cycle of the run has a row."""
    loop, _drives, _ten, _sup = make_loop()
    loop.start()
    try:
        sink = StallingSink(stall_s=0.03)  # one long cycle with missed deadlines
        run = loop.follow(Ramp(0.1, 0.3), "r", None, sink)
        assert wait_until(lambda: run.state != "running")
        rows = sink.rows
        assert sink.stalled_at is not None
        cycles = [r["cycle"] for r in rows]
        assert cycles == list(range(run.first_cycle, run.last_cycle + 1))  # no cycle unlogged
        assert run.rows == len(rows)
        assert run.long_cycles >= 1 and run.missed_cycles >= 1
        assert _flagged(rows, "late") == run.missed_cycles
        assert _flagged(rows, "long") == run.long_cycles
        # The stalled cycle's own lateness reaches the next row only.
        after = next(r for r in rows if r["cycle"] == sink.stalled_at + 1)
        assert "long: previous cycle" in after["event"]
    finally:
        loop.stop()
