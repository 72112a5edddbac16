"""The loop on an injected clock: the lock-step SimClock (cycle times from the cycle count, the
world advanced between cycles, no cycle while the loop has nothing to do)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from test_loop import CPM, FakeModel, ListSink, Ramp, clocked_loop, wait_until

from cdcr_ctl.control.clock import wall_clock
from cdcr_ctl.control.loop import COMMAND_STEP_FRACTION, LoopConfig
from cdcr_ctl.control.timing import Ticker
from cdcr_ctl.sim.lockstep.clock import SimClock

PERIOD = 0.002


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
    loop = clocked_loop(clock)
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
    loop = clocked_loop(None)
    assert isinstance(loop.ticker, Ticker) and isinstance(wall_clock(0.01), Ticker)
    assert abs(loop.ticker.now() - time.monotonic()) < 1.0


class SelfRampingModel(FakeModel):
    """Like the universal-joint model: its mode ``model`` command starts from the bare geometry
    and moves its compensation term towards +2 mm on every cable by at most ``frac`` of the
    velocity limit per cycle, on its own; mode ``off`` sits 1 mm below the geometry (so a switch
    to ``model`` is a step up the loop's offset ramp takes out, in the same direction)."""

    def __init__(self, v_dt_mm: float, frac: float = 0.9) -> None:
        self.step = frac * v_dt_mm

    def new_state(self):
        return {"delta": 0.0}

    def q_command(self, psi, q_nominal, state, mode, measured_N):
        if mode != "model":
            state["delta"] = 0.0
            return q_nominal - 1.0
        state["delta"] = min(2.0, state["delta"] + self.step)
        return q_nominal + state["delta"]


def test_an_offset_ramp_and_a_self_ramping_model_stay_within_the_velocity_limit_together():
    # Switching off -> model: the loop takes the step into an offset it ramps out at half the
    # limit, while the model ramps its own term at 0.9 of the limit, the same way. Each alone is
    # within the limit; added they were not (1.4x, as the universal-joint demo tripped). The loop
    # gives the offset only what the model's step leaves of COMMAND_STEP_FRACTION of the limit.
    v = 100.0  # mm/s, LoopConfig's cable_velocity_mm_s below
    v_dt = v * PERIOD
    clock = SimClock(PERIOD, advance=lambda t0, t1: None)
    loop = clocked_loop(
        clock,
        LoopConfig(period_s=PERIOD, counts_per_mm=CPM, compensation="off", cable_velocity_mm_s=v),
        SelfRampingModel(v_dt),
    )
    loop.start()
    try:
        sink = ListSink()
        first = loop.follow(Ramp(0.0, 0.02), "off", "off", ListSink())
        assert wait_until(lambda: first.state != "running")
        run = loop.follow(Ramp(0.0, 0.3), "switch", "model", sink)
        assert wait_until(lambda: run.state != "running")
    finally:
        loop.stop()
    assert run.state == "completed", run.end_reason
    q = np.array([[r[f"cable{k}_q_cmd_mm"] for k in range(1, 4)] for r in sink.rows])
    # From the last "off" command (-1 mm) on, no cycle steps further than the loop promises
    # (COMMAND_STEP_FRACTION of the limit), up to float rounding.
    steps = np.abs(np.diff(np.vstack(([-1.0] * 3, q)), axis=0))
    assert steps.max() <= COMMAND_STEP_FRACTION * v_dt + 1e-9
    assert q[-1] == pytest.approx([2.0] * 3)  # the offset ramped out, the model's term arrived
