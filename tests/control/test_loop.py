"""The control loop against fake drives, sensors and model: data flow, run lifecycle, reactions."""

from __future__ import annotations

import itertools
import threading
import time

import numpy as np
import pytest

from cdcr_ctl.config.control import LimitsConfig
from cdcr_ctl.control.loop import ControlLoop, Hold, LoopConfig
from cdcr_ctl.control.ports import DriveState, NoTip
from cdcr_ctl.control.supervisor import Reaction, Supervisor

K = 3
CPM = np.array([1000.0, 1000.0, -500.0])


class FakeModel:
    """q_nominal = 10 * theta * cos(phi - gamma_k); 'model' compensation adds +0.1 mm."""

    n_segments = 1
    n_cables = K
    gammas = np.array([0.0, 2.0944, 4.1888])

    def new_state(self):
        return {"calls": 0}

    def q_nominal(self, psi):
        th, ph = psi[0]
        return 10.0 * th * np.cos(ph - self.gammas)

    def q_command(self, psi, q_nominal, state, mode, measured_N):
        state["calls"] += 1
        return q_nominal + (0.1 if mode == "model" else 0.0)

    def tip(self, psi):
        return np.array([0.0, 0.0, 90.0])


class FakeDrives:
    def __init__(self):
        self.sent = []
        self.pos = [0, 0, 0]
        self.quick_stops = 0
        self.fault = None
        self.lock = threading.Lock()

    def send_cycle(self, targets):
        with self.lock:
            self.sent.append(list(targets))
            self.pos = list(targets)

    def feedback(self):
        return [DriveState(p, "OPERATION_ENABLED", "", 0.0) for p in self.pos]

    def first_fault(self):
        return self.fault

    def quick_stop(self):
        self.quick_stops += 1


class FakeTension:
    def __init__(self):
        self.f = np.array([3.0, 3.0, 3.0])

    def latest(self):
        return self.f.copy(), np.zeros(K)


class ListSink:
    def __init__(self):
        self.rows = []
        self.closed = None
        self.failure = None

    def write(self, row):
        self.rows.append(row)
        return True

    def close(self, reason, outcome=None, wait=True):
        self.closed = reason


class Ramp:
    def __init__(self, theta_end, duration):
        self.theta_end, self.duration = theta_end, duration

    @property
    def duration_s(self):
        return self.duration

    def sample(self, t):
        return np.array([[self.theta_end * min(t / self.duration, 1.0), 0.0]])


LIM = LimitsConfig(
    cable_displacement_mm=[-20.0, 20.0], cable_velocity_mm_s=100.0, tension_N=[0.5, 30.0]
)


def make_loop(
    tension=None, model=None, compensation="model", home_counts=(100, 200, 300), drives=None
):
    """A loop on fake drives (``drives``, default :class:`FakeDrives`) at 500 Hz with a 100 mm/s
    velocity limit: (loop, drives, tension, supervisor)."""
    drives = drives or FakeDrives()
    ten = tension or FakeTension()
    sup = Supervisor(LIM, use_tension=True)
    loop = ControlLoop(
        LoopConfig(
            period_s=0.002,
            counts_per_mm=CPM,
            compensation=compensation,
            cable_velocity_mm_s=100.0,
        ),
        model or FakeModel(),
        drives,
        ten,
        NoTip(),
        sup,
        home_counts=list(home_counts),
    )
    return loop, drives, ten, sup


def clocked_loop(clock, config=None, model=None):
    """A loop on fake drives on ``clock`` (None: the wall clock); ``config`` by default 500 Hz,
    compensation ``model``, no velocity limit of its own. A simulated clock runs while the loop
    is busy."""
    loop = ControlLoop(
        config or LoopConfig(period_s=0.002, counts_per_mm=CPM, compensation="model"),
        model or FakeModel(),
        FakeDrives(),
        FakeTension(),
        NoTip(),
        Supervisor(LIM, use_tension=True),
        clock=clock,
    )
    if clock is not None:
        clock.busy = lambda: loop.busy
    return loop


def wait_until(pred, timeout=10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return False


def test_trajectory_runs_to_completion_and_logs_every_cycle():
    loop, drives, _, _ = make_loop()
    loop.start()
    try:
        sink = ListSink()
        run = loop.follow(Ramp(0.5, 0.2), "ramp", "model", sink)
        assert wait_until(lambda: run.state != "running")
        assert run.state == "completed" and sink.closed == "trajectory completed"
    finally:
        loop.stop()
    last = sink.rows[-1]
    q_nom = 10.0 * 0.5 * np.cos(0.0 - FakeModel.gammas)
    assert last["seg1_theta_cmd_rad"] == pytest.approx(0.5)
    assert [last[f"cable{k}_q_nominal_mm"] for k in (1, 2, 3)] == pytest.approx(q_nom)
    assert [last[f"cable{k}_q_cmd_mm"] for k in (1, 2, 3)] == pytest.approx(q_nom + 0.1)
    # counts = home + q_cmd * counts_per_mm, rounded; actual follows the fake drive
    expected = np.rint(np.array([100, 200, 300]) + (q_nom + 0.1) * CPM).astype(int).tolist()
    assert expected in drives.sent
    assert [last[f"cable{k}_tension_N"] for k in (1, 2, 3)] == [3.0, 3.0, 3.0]
    t = [r["t_s"] for r in sink.rows]
    assert all(b > a for a, b in itertools.pairwise(t))


def test_overload_quick_stops_once_and_ends_the_run():
    loop, drives, ten, sup = make_loop()
    loop.start()
    try:
        sink = ListSink()
        run = loop.follow(Ramp(0.5, 5.0), "ramp", "off", sink)
        assert wait_until(lambda: len(sink.rows) > 5)
        ten.f = np.array([3.0, 35.0, 3.0])
        assert wait_until(lambda: run.state == "tripped")
        time.sleep(0.05)
    finally:
        loop.stop()
    assert drives.quick_stops == 1
    assert sup.trip.cause == "tension_high:cable2" and sup.trip.reaction is Reaction.QUICK_STOP
    assert sink.closed.startswith("tension_high:cable2")
    # The trip first; a row may go on with notes ("; late: ...", "; long: ...").
    assert any(r["event"].split("; ")[0] == "tension_high:cable2" for r in sink.rows)


def test_drive_fault_quick_stops_and_new_runs_are_refused():
    loop, drives, _, sup = make_loop()
    loop.start()
    try:
        assert wait_until(lambda: loop.counters.cycles > 3)
        drives.fault = ("emcy:node2:0x8611", "node 2: 0x8611 following error")
        assert wait_until(lambda: drives.quick_stops == 1)
        sink = ListSink()
        run = loop.follow(Ramp(0.2, 0.1), "after-fault", "off", sink)
        assert wait_until(lambda: run.state != "running")
    finally:
        loop.stop()
    assert run.state == "refused" and "emcy:node2:0x8611" in sink.closed
    assert sup.trip.cause == "emcy:node2:0x8611"


def test_displacement_limit_holds_the_last_safe_command():
    loop, drives, _, sup = make_loop()
    loop.start()
    try:
        sink = ListSink()
        run = loop.follow(Ramp(3.0, 1.0), "too-far", "off", sink)  # 10*3 = 30 mm > 20 mm limit
        assert wait_until(lambda: run.state != "running")
    finally:
        loop.stop()
    assert run.state == "tripped" and sup.trip.reaction is Reaction.HOLD
    sent_q = [(np.array(s) - [100, 200, 300]) / CPM for s in drives.sent]
    assert max(np.max(np.abs(q)) for q in sent_q) <= 20.0 + 1e-9
    assert drives.quick_stops == 0


def test_hold_source():
    h = Hold(np.array([[0.1, 0.2]]))
    assert h.duration_s == float("inf")
    assert h.sample(123.0).tolist() == [[0.1, 0.2]]


def test_a_row_is_the_run_log_columns_made_off_the_loop():
    """The loop keeps a cycle's numbers; the mapping (run-log column names, in order) is made
    when the writer or a status request first reads it."""
    from cdcr_ctl.control.loop import CycleRow, RowLayout

    layout = RowLayout(2, 3)
    psi = np.array([[0.1, 0.2], [0.3, 0.4]])
    q_nom, q_cmd, q_act = (
        np.array([1.0, 2, 3]),
        np.array([1.5, 2.5, 3.5]),
        np.array([1.1, 2.1, 3.1]),
    )
    force, tip = np.array([4.0, 5, 6]), np.array([7.0, 8, 9])
    values = np.concatenate((psi.ravel(), q_nom, q_cmd, q_act, force, tip))
    row = CycleRow(layout, 1.23456789, 42, values, 12.34e-6, "ev")
    want = {"t_s": 1.234568, "cycle": 42}
    want.update({"seg1_theta_cmd_rad": 0.1, "seg1_phi_cmd_rad": 0.2})
    want.update({"seg2_theta_cmd_rad": 0.3, "seg2_phi_cmd_rad": 0.4})
    for k in range(3):
        want[f"cable{k + 1}_q_nominal_mm"] = q_nom[k]
        want[f"cable{k + 1}_q_cmd_mm"] = q_cmd[k]
        want[f"cable{k + 1}_q_act_mm"] = q_act[k]
        want[f"cable{k + 1}_tension_N"] = force[k]
    want.update({"tip_x_mm": 7.0, "tip_y_mm": 8.0, "tip_z_mm": 9.0})
    want.update({"lateness_us": 12.3, "event": "ev"})
    assert list(row) == list(want) and dict(row) == want
    assert row["cable2_q_act_mm"] == 2.1 and row.get("nope", "-") == "-" and "tip_z_mm" in row
    assert len(row) == len(want) and all(type(v) is float for v in list(row.values())[2:-2])


class ReusedArrayTension(FakeTension):
    """Returns the same array object every cycle, rewritten in place (3.0, 3.001, ...)."""

    def __init__(self):
        super().__init__()
        self.n = 0

    def latest(self):
        self.f[:] = 3.0 + 0.001 * self.n
        self.n += 1
        return self.f, np.zeros(K)


def test_rows_are_snapshots_and_stages_are_timed():
    ten = ReusedArrayTension()
    loop, _, _, _ = make_loop(ten)
    loop.start()
    try:
        sink = ListSink()
        run = loop.follow(Ramp(0.5, 0.2), "ramp", "model", sink)
        assert wait_until(lambda: run.state != "running")
    finally:
        loop.stop()
    # Each row keeps the tension of its own cycle, though the port rewrote the array since.
    got = [r["cable1_tension_N"] for r in sink.rows]
    assert len(set(got)) == len(got) and got == sorted(got)
    c = loop.counters
    assert set(c.stage_mean_us()) == {"inputs", "model", "checks", "send", "log"}
    assert all(v > 0 for v in c.stage_s.values()) and c.work_cpu_s > 0
    assert all(c.stage_max_us[k] >= c.stage_mean_us()[k] for k in c.stage_s)
    c.reset_timing()
    assert c.stage_mean_us() == dict.fromkeys(c.stage_s, 0.0) and c.work_cpu_us() == 0.0


class BrokenModel(FakeModel):
    """A model with a bug: raises something that is not a ModelError after a few cycles."""

    def __init__(self):
        self.calls = 0

    def q_command(self, psi, q_nominal, state, mode, measured_N):
        self.calls += 1
        if self.calls > 5:
            raise ZeroDivisionError("a bug")
        return super().q_command(psi, q_nominal, state, mode, measured_N)


def test_a_cycle_that_raises_quick_stops_the_drives_and_the_loop_goes_on():
    drives = FakeDrives()
    sup = Supervisor(LIM, use_tension=True)
    loop = ControlLoop(
        LoopConfig(period_s=0.002, counts_per_mm=CPM, compensation="model"),
        BrokenModel(),
        drives,
        FakeTension(),
        NoTip(),
        sup,
        home_counts=[100, 200, 300],
    )
    loop.start()
    try:
        assert wait_until(lambda: drives.quick_stops == 1)
        n = loop.counters.cycles
        assert wait_until(lambda: loop.counters.cycles > n + 5)
        assert loop.running
    finally:
        loop.stop()
    assert sup.trip.cause == "loop_exception" and sup.trip.reaction is Reaction.QUICK_STOP
    assert "ZeroDivisionError: a bug" in sup.trip.detail


def test_commands_of_one_cycle_apply_in_the_order_posted():
    """Commands posted between two cycles all apply at the next one, in posting order: a stop
    after a new run ends that run; a run after a home is not replaced by the home's hold."""
    loop, drives, _, _ = make_loop()
    first = ListSink()
    run1 = loop.follow(Ramp(0.5, 5.0), "ramp", "off", first)
    loop.request_stop(Reaction.HALT)
    loop.start()
    try:
        assert wait_until(lambda: run1.state != "running")
        assert run1.state == "stopped" and first.closed.startswith("operator_stop")
        loop.set_home([0, 0, 0])
        second = ListSink()
        run2 = loop.follow(Ramp(0.5, 0.1), "ramp", "off", second)
        assert wait_until(lambda: run2.state != "running")
    finally:
        loop.stop()
    assert run2.state == "completed", run2.end_reason
    # The run moved from the new home: theta 0.5 -> q1 = 5 mm -> 5000 counts from 0.
    assert drives.sent[-1][0] == 5000


def test_jogs_after_a_new_run_in_the_same_cycle_add_up_and_are_kept():
    loop, drives, _, _ = make_loop()
    loop.follow(Hold(np.zeros((1, 2))), "hold", "off")
    loop.jog_cable(0, 1.5)
    loop.jog_cable(0, 0.5)
    loop.start()
    try:
        # cable 1: home 100 counts + 2.0 mm x 1000 counts/mm, reached at the offset ramp rate
        assert wait_until(lambda: drives.sent and drives.sent[-1][0] == 2100)
        time.sleep(0.05)
    finally:
        loop.stop()
    assert drives.sent[-1] == [2100, 200, 300]


class StraightOffsetModel(FakeModel):
    """'model' compensation adds 0.5 mm at every pose, straight included (as a fitted mount
    tilt does): more than one cycle's velocity budget (100 mm/s x 2 ms = 0.2 mm)."""

    def q_command(self, psi, q_nominal, state, mode, measured_N):
        state["calls"] += 1
        return q_nominal + (0.5 if mode == "model" else 0.0)


def test_home_ramps_in_a_compensation_that_is_not_zero_at_straight():
    """Home makes the drives' positions the straight pose. The model's command there is not
    zero: the home starts from it in the offset and ramps it in (at most half the velocity
    limit per cycle) instead of stepping 0.5 mm in one cycle (250 mm/s: a velocity trip)."""
    loop, drives, _, sup = make_loop(
        model=StraightOffsetModel(), compensation="off", home_counts=(0, 0, 0)
    )
    loop.start()
    try:
        assert wait_until(lambda: len(drives.sent) > 5)
        loop.set_compensation("model")
        n_mode = len(drives.sent)
        assert wait_until(lambda: len(drives.sent) > n_mode + 30)
        home = list(drives.pos)
        n0 = len(drives.sent) - 1  # from the last command before the home
        loop.set_home(home)
        assert wait_until(lambda: len(drives.sent) > n0 + 30)
    finally:
        loop.stop()
    assert sup.trip is None, sup.trip
    sent = np.array(drives.sent[n0:], dtype=float)
    steps = np.abs(np.diff(sent, axis=0)) / np.abs(CPM)  # mm per cycle
    assert steps.max() <= 0.5 * 0.2 + 1e-3  # the offset ramp: half the limit per cycle
    np.testing.assert_allclose(sent[-1], np.array(home) + 0.5 * CPM)


class UnpoweredWhenStopped(FakeDrives):
    """Fake drives whose quick stop switches the power stage off until :meth:`reenable`: targets
    sent meanwhile are recorded but move nothing (a real drive in QUICK STOP ACTIVE or FAULT
    ignores its RPDO targets), so a position the test back-drives stays where it was put."""

    def __init__(self):
        super().__init__()
        self.powered = True

    def send_cycle(self, targets):
        with self.lock:
            self.sent.append(list(targets))
            if self.powered:
                self.pos = list(targets)

    def quick_stop(self):
        with self.lock:
            self.powered = False
        super().quick_stop()

    def reenable(self):
        with self.lock:
            self.powered = True


class SlackCable1(FakeTension):
    """Cable 1 reads slack (0 N) while its drive is paid out below ``taut_counts``, as a cable
    whose motor was back-driven by its tension while the power stage was off; 3 N otherwise."""

    def __init__(self):
        super().__init__()
        self.drives = FakeDrives()
        self.taut_counts = -(10**9)

    def latest(self):
        f = self.f.copy()
        if self.drives.pos[0] < self.taut_counts:
            f[0] = 0.0
        return f, np.zeros(K)


def test_a_cable_paid_out_during_a_fault_is_pulled_back_in_by_the_next_run():
    """A drive fault (power stage off) lets cable 1's tension back-drive its motor by 0.5 mm; after
    the reset and re-enable the loop starts from where the drives are, and the next run ramps that
    step out, pulling the cable back in: the slack it reads meanwhile is not a ``tension_low``
    trip, the run completes and the cable is taut again. A cable that stays slack while nothing
    pulls it in still trips."""
    loop, drives, ten, sup = make_loop(tension=SlackCable1(), drives=UnpoweredWhenStopped())
    ten.drives = drives  # the tension reads the loop's drives
    loop.start()
    try:
        assert wait_until(lambda: loop.counters.cycles > 5)
        ten.taut_counts = drives.pos[0] - 100  # up to 0.1 mm paid out still taut
        drives.fault = ("emcy:node1:0x2310", "node 1: 0x2310 over current")
        assert wait_until(lambda: drives.quick_stops == 1)
        with drives.lock:
            drives.pos[0] -= 500  # 0.5 mm back-driven while unpowered
        assert wait_until(lambda: ten.latest()[0][0] == 0.0)
        drives.fault = None
        sup.reset()
        drives.reenable()  # the daemon's fault reset and enable
        loop.drives_reenabled()
        assert wait_until(lambda: not loop._stopped_drives)
        sink = ListSink()
        run = loop.follow(Ramp(0.0, 0.5), "after-recovery", "off", sink)
        assert wait_until(lambda: run.state != "running")
        assert run.state == "completed", (run.state, sink.closed, sup.trip)
        assert sup.trip is None
        assert drives.pos[0] >= ten.taut_counts and ten.latest()[0][0] == 3.0
        # Slack rows were logged while the run pulled the cable in, then none.
        slack = [i for i, r in enumerate(sink.rows) if r["cable1_tension_N"] == 0.0]
        assert slack and slack[-1] < len(sink.rows) - 1
        # Nothing pulling it in: a slack cable trips as before.
        ten.taut_counts = 10**9
        run = loop.follow(Ramp(0.0, 0.5), "slack", "off", ListSink())
        assert wait_until(lambda: run.state != "running")
        assert run.state == "tripped" and sup.trip.cause == "tension_low:cable1"
    finally:
        loop.stop()
