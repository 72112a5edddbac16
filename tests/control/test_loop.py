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


def make_loop(tension=None):
    drives = FakeDrives()
    ten = tension or FakeTension()
    sup = Supervisor(LIM, use_tension=True)
    loop = ControlLoop(
        LoopConfig(
            period_s=0.002, counts_per_mm=CPM, compensation="model", cable_velocity_mm_s=100.0
        ),
        FakeModel(),
        drives,
        ten,
        NoTip(),
        sup,
        home_counts=[100, 200, 300],
    )
    return loop, drives, ten, sup


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
    assert any(r["event"] == "tension_high:cable2" for r in sink.rows)


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
