"""The loop on an injected clock: the lock-step SimClock (cycle times from the cycle count, the
world advanced between cycles, no cycle while the loop has nothing to do)."""

from __future__ import annotations

import time

import pytest
from test_loop import CPM, LIM, FakeDrives, FakeModel, FakeTension, ListSink, Ramp, wait_until

from cdcr_ctl.control.clock import wall_clock
from cdcr_ctl.control.loop import ControlLoop, LoopConfig
from cdcr_ctl.control.ports import NoTip
from cdcr_ctl.control.supervisor import Supervisor
from cdcr_ctl.control.timing import Ticker
from cdcr_ctl.sim.lockstep.clock import SimClock

PERIOD = 0.002


def _loop(clock):
    return ControlLoop(
        LoopConfig(period_s=PERIOD, counts_per_mm=CPM, compensation="model"),
        FakeModel(),
        FakeDrives(),
        FakeTension(),
        NoTip(),
        Supervisor(LIM, use_tension=True),
        clock=clock,
    )


def test_sim_clock_time_is_the_cycle_count_and_the_world_advances_between_cycles():
    steps = []
    clock = SimClock(0.004, advance=lambda t0, t1: steps.append((t0, t1)), t0_s=0.1)
    assert clock.wait() == (0.1, 0.0) and steps == []  # the first cycle advances nothing
    for _ in range(3):
        clock.wait()
        clock.done()
    assert clock.now() == pytest.approx(0.1 + 3 * 0.004)
    flat = [t for step in steps for t in step]
    assert flat == pytest.approx([0.1, 0.104, 0.104, 0.108, 0.108, 0.112])
    assert clock.stats.cycles == 4 and clock.stats.max_us == 0.0


def test_the_loop_runs_on_the_injected_clock_and_only_while_it_has_work():
    advanced = []
    clock = SimClock(PERIOD, advance=lambda t0, t1: advanced.append(t1))
    loop = _loop(clock)
    clock.busy = lambda: loop.busy
    loop.start()
    try:
        time.sleep(0.05)  # idle: no run, nothing posted -> the simulated clock stands still
        assert clock.cycles == 0 and loop.counters.cycles == 0
        sink = ListSink()
        run = loop.follow(Ramp(0.5, 0.2), "ramp", "model", sink)
        assert wait_until(lambda: run.state != "running")
        assert run.state == "completed"
        n = clock.cycles
        time.sleep(0.05)
        assert clock.cycles == n  # the run ended: idle again, no further cycles
    finally:
        loop.stop()
    t = [r["t_s"] for r in sink.rows]
    # Simulated time: every cycle exactly one period after the last, never late, and the run
    # took its 0.2 s of that time whatever the wall clock did.
    assert t == pytest.approx([t[0] + k * PERIOD for k in range(len(t))], abs=1e-6)
    assert {r["lateness_us"] for r in sink.rows} == {0.0}
    assert len(t) == pytest.approx(0.2 / PERIOD + 1, abs=1)
    assert advanced == pytest.approx([k * PERIOD for k in range(1, len(advanced) + 1)])


def test_the_default_clock_is_the_wall_clock():
    loop = _loop(None)
    assert isinstance(loop.ticker, Ticker) and isinstance(wall_clock(0.01), Ticker)
    assert abs(loop.ticker.now() - time.monotonic()) < 1.0
