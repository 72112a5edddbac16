"""Mode ``measured`` on the lock-step SimClock: its compensation term is rate-bounded like the
dead zone's pre-travel, and a recovery after a velocity trip does not re-latch the same trip."""

from __future__ import annotations

import numpy as np
import pytest
from test_loop import CPM, LIM, FakeDrives, FakeModel, ListSink, Ramp, wait_until

from cdcr_ctl.control.loop import COMMAND_STEP_FRACTION, ControlLoop, LoopConfig
from cdcr_ctl.control.ports import NoTip
from cdcr_ctl.control.supervisor import Supervisor
from cdcr_ctl.sim.lockstep.clock import SimClock

PERIOD = 0.002
V = 100.0  # mm/s: LIM's cable velocity limit and the loop's
V_DT = V * PERIOD  # 0.2 mm per cycle
GAIN_MM_PER_N = 0.5


class MeasuredModel(FakeModel):
    """``measured``: q_nominal + GAIN_MM_PER_N (T - 3 N) per cable; ``model``: q_nominal +
    ``bump`` once the model has been called ``bump_after`` times (a compensation that steps)."""

    def __init__(self, bump_after: int | None = None) -> None:
        self.bump_after = bump_after

    def q_command(self, psi, q_nominal, state, mode, measured_N):
        state["calls"] += 1
        if mode == "measured":
            return q_nominal + GAIN_MM_PER_N * (np.asarray(measured_N) - 3.0)
        bumped = self.bump_after is not None and state["calls"] > self.bump_after
        return q_nominal + (1.0 if bumped else 0.0)


class SteppingTension:
    """3 N on every cable, then (from read ``at`` on) 5 N on cable 1 and 2 N on cable 3: the
    measured term steps by +1 mm and -0.5 mm in one cycle (5x and 2.5x the limit's step)."""

    def __init__(self, at: int) -> None:
        self.at, self.reads = at, 0

    def latest(self):
        self.reads += 1
        f = np.array([5.0, 3.0, 2.0]) if self.reads > self.at else np.array([3.0, 3.0, 3.0])
        return f, np.zeros(3)


def _loop(model, tension, mode):
    clock = SimClock(PERIOD, advance=lambda t0, t1: None)
    sup = Supervisor(LIM, use_tension=True)
    loop = ControlLoop(
        LoopConfig(period_s=PERIOD, counts_per_mm=CPM, compensation=mode, cable_velocity_mm_s=V),
        model,
        FakeDrives(),
        tension,
        NoTip(),
        sup,
        clock=clock,
    )
    clock.busy = lambda: loop.busy
    return loop, sup


def _q(sink):
    return np.array([[r[f"cable{k}_q_cmd_mm"] for k in range(1, 4)] for r in sink.rows])


def test_a_tension_step_moves_the_measured_command_within_the_velocity_limit():
    loop, sup = _loop(MeasuredModel(), SteppingTension(at=40), "measured")
    sink = ListSink()
    loop.start()
    try:
        run = loop.follow(Ramp(0.3, 0.3), "bend", "measured", sink)
        assert wait_until(lambda: run.state != "running")
    finally:
        loop.stop()
    # Before the bound: velocity_limit:cable1 at 0.5 mm/cycle above the trajectory's own step.
    assert run.state == "completed", run.end_reason
    assert sup.trip is None and not sup.history
    q = _q(sink)
    steps = np.abs(np.diff(q, axis=0))
    assert steps.max() <= COMMAND_STEP_FRACTION * V_DT + 1e-9
    # The bound delays the term, it does not drop it: at the end the command is the model's.
    q_nom_end = 10.0 * 0.3 * np.cos(0.0 - FakeModel.gammas)
    np.testing.assert_allclose(q[-1], q_nom_end + GAIN_MM_PER_N * np.array([2.0, 0.0, -1.0]))
    # It took the +1 mm of cable 1 over several cycles (at most the budget each).
    assert (steps[:, 0] > 0.5 * V_DT).sum() >= 1.0 / (COMMAND_STEP_FRACTION * V_DT) - 1


def test_a_recovery_after_a_velocity_trip_does_not_trip_again():
    # A compensation that steps 1 mm at once (5x the limit's step) trips the velocity limit
    # while holding; after the operator's reset the next run must start from the command the
    # drives hold, not ask for the refused step again.
    loop, sup = _loop(MeasuredModel(bump_after=20), SteppingTension(at=10**9), "model")
    loop.start()
    try:
        first = loop.follow(Ramp(0.0, 0.2), "hold", "model", ListSink())
        assert wait_until(lambda: first.state != "running")
        assert first.state == "tripped" and first.end_reason.startswith("velocity_limit")
        held = loop.q_cmd
        sup.reset()  # reset-fault
        loop.drives_reenabled()  # enable
        sink = ListSink()
        run = loop.follow(Ramp(0.0, 0.2), "after", "model", sink)
        assert wait_until(lambda: run.state != "running")
    finally:
        loop.stop()
    assert run.state == "completed", run.end_reason  # before: velocity_limit again
    assert sup.trip is None and len(sup.history) == 1
    q = _q(sink)
    steps = np.abs(np.diff(np.vstack((held, q)), axis=0))
    assert steps.max() <= COMMAND_STEP_FRACTION * V_DT + 1e-9
    # The refused step went into the offset and the run ramped it out: the model's command.
    assert q[-1] == pytest.approx(held + 1.0)
