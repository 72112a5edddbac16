"""Joystick: axis normalisation and deadband by hand, the event state machine on recorded event
streams (reports, buttons, SYN_DROPPED, a disconnect), scripted sources, the lazy evdev import and
the evdev adapter over a pipe, and a property test on random events."""

from __future__ import annotations

import errno
import os
import struct
import sys
import time
from collections.abc import Callable, Iterator
from types import SimpleNamespace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.config.tracking import JoystickConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.joystick import (
    ABS_CODES,
    BUTTON_CODES,
    EV_ABS,
    EV_KEY,
    EV_SYN,
    SYN_DROPPED,
    SYN_REPORT,
    AxisRange,
    Joystick,
    axis_code,
    open_evdev_joystick,
)
from cdcr_ctl.sim.joystick import CallableJoystick, JoystickFrame, ScriptedJoystick

WAIT_S = 5.0
X, Y = ABS_CODES["ABS_X"], ABS_CODES["ABS_Y"]
SOUTH = BUTTON_CODES["BTN_SOUTH"]
BYTE = AxisRange(0, 255)


def wait_until(pred: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


# -- normalisation --------------------------------------------------------------------------


def test_normalise_by_hand() -> None:
    assert BYTE.normalise(0) == -1.0
    assert BYTE.normalise(255) == 1.0
    assert BYTE.normalise(127) == pytest.approx(-0.5 / 127.5)
    r = AxisRange(-100, 100)
    assert r.normalise(50) == 0.5
    assert r.normalise(500) == 1.0  # out of range clips
    # deadband 0.1: |u| <= 0.1 reads 0, then (|u| - 0.1) / 0.9
    assert r.normalise(10, 0.1) == 0.0
    assert r.normalise(-10, 0.1) == 0.0
    assert r.normalise(55, 0.1) == pytest.approx(0.5)
    assert r.normalise(-100, 0.1) == -1.0
    assert r.raw(0.5) == 50 and r.raw(-2.0) == -100
    with pytest.raises(ValueError):
        AxisRange(5, 5)


def test_axis_names() -> None:
    assert axis_code("ABS_RY") == 4
    with pytest.raises(ValueError, match="unknown joystick axis 'ABS_Q'"):
        axis_code("ABS_Q")


# -- recorded events ------------------------------------------------------------------------


class FakeClock:
    def __init__(self) -> None:
        self.t = 10.0

    def __call__(self) -> float:
        return self.t


def stick(**kw: object) -> Joystick:
    kw.setdefault("axis_ranges", {X: BYTE, Y: BYTE})
    kw.setdefault("deadband", 0.1)
    kw.setdefault("clock", FakeClock())
    return Joystick([], **kw)


def test_state_is_published_at_reports_only() -> None:
    j = stick()
    assert j.latest().seq == 0 and j.latest().x == 0.0
    j.handle_event(EV_ABS, X, 255)
    j.handle_event(EV_KEY, SOUTH, 1)
    assert j.latest().seq == 0  # not yet: no SYN_REPORT
    assert j.handle_event(EV_SYN, SYN_REPORT, 0)
    s = j.latest()
    assert (s.x, s.y, s.buttons, s.seq) == (1.0, 0.0, frozenset({"BTN_SOUTH"}), 1)
    assert s.connected and s.t_s == 10.0
    j.handle_event(EV_ABS, Y, 0)
    j.handle_event(EV_KEY, SOUTH, 0)
    j.handle_event(EV_KEY, 0x2C0, 2)  # some other key, autorepeat
    j.handle_event(EV_SYN, SYN_REPORT, 0)
    s = j.latest()
    assert (s.x, s.y, s.buttons) == (1.0, -1.0, frozenset({"KEY_704"}))
    assert dict(s.axes) == {"ABS_X": 1.0, "ABS_Y": -1.0}


def test_invert_and_deadband_and_initial_values() -> None:
    j = stick(invert_y=True, initial={X: 128, Y: 0})
    s = j.latest()  # before any report: the device's initial values
    assert s.x == 0.0 and s.y == 1.0 and s.seq == 0
    j.handle_event(EV_ABS, X, 140)  # u = 12.5 / 127.5 < 0.1: inside the deadband
    j.handle_event(EV_SYN, SYN_REPORT, 0)
    assert j.latest().x == 0.0


def test_syn_dropped_discards_until_report_and_resyncs() -> None:
    j = stick(resync=lambda: ({X: 0, Y: 255}, [SOUTH]))
    j.handle_event(EV_ABS, X, 200)
    j.handle_event(EV_SYN, SYN_REPORT, 0)
    j.handle_event(EV_SYN, SYN_DROPPED, 0)
    j.handle_event(EV_ABS, X, 255)  # lost with the drop
    j.handle_event(EV_SYN, SYN_REPORT, 0)
    s = j.latest()
    assert (s.x, s.y, s.buttons) == (-1.0, 1.0, frozenset({"BTN_SOUTH"}))
    assert j.stats.dropped == 1 and j.stats.ignored == 1 and j.stats.reports == 2


def test_recorded_source_with_disconnect_mid_run() -> None:
    def source() -> Iterator[tuple[int, int, int] | None]:
        yield (EV_ABS, X, 0)
        yield None  # idle tick
        yield (EV_SYN, SYN_REPORT, 0)
        yield (EV_ABS, X, 255)  # the cable is pulled before this report completes
        raise OSError(errno.ENODEV, "No such device")

    j = Joystick(source(), name="/dev/input/event7", axis_ranges={X: BYTE}, deadband=0.0)
    with j:
        assert wait_until(lambda: j.failure is not None)
        assert isinstance(j.failure, SensorError) and j.failure.port == "/dev/input/event7"
        assert "disconnected" in str(j.failure)
        s = j.latest()
        assert s.x == -1.0 and s.seq == 1 and not s.connected


# -- simulated sources ----------------------------------------------------------------------


def test_scripted_source_not_realtime() -> None:
    script = [
        JoystickFrame(0.0),
        JoystickFrame(0.1, 0.5, -0.25, frozenset({"BTN_TRIGGER"})),
        JoystickFrame(0.2, 0.5, -0.25),  # only the button changes
        JoystickFrame(0.3, 0.5, -0.25),  # nothing changes: no events
    ]
    src = ScriptedJoystick(script, realtime=False)
    events = list(src)
    trigger = BUTTON_CODES["BTN_TRIGGER"]
    # Over -32768..32767: 0 -> round(-0.5) = 0, 0.5 -> round(16383.25), -0.25 -> round(-8192.375)
    assert events == [
        (EV_ABS, X, 0),
        (EV_ABS, Y, 0),
        (EV_SYN, SYN_REPORT, 0),
        (EV_ABS, X, 16383),
        (EV_ABS, Y, -8192),
        (EV_KEY, trigger, 1),
        (EV_SYN, SYN_REPORT, 0),
        (EV_KEY, trigger, 0),
        (EV_SYN, SYN_REPORT, 0),
    ]
    j = Joystick(events, axis_ranges=src.ranges, deadband=0.0, clock=FakeClock())
    j.start()
    assert wait_until(lambda: j.finished)
    s = j.latest()
    assert s.x == pytest.approx(0.5, abs=1e-4) and s.y == pytest.approx(-0.25, abs=1e-4)
    assert s.buttons == frozenset() and s.seq == 3 and j.failure is None
    j.close()
    with pytest.raises(ValueError, match="time order"):
        ScriptedJoystick([JoystickFrame(1.0), JoystickFrame(0.5)])
    with pytest.raises(ValueError, match="unknown button"):
        list(
            ScriptedJoystick([JoystickFrame(0.0, buttons=frozenset({"BTN_NOPE"}))], realtime=False)
        )


def test_scripted_source_in_real_time_then_unplugged() -> None:
    src = ScriptedJoystick(
        [JoystickFrame(0.0, 0.0, 0.0), JoystickFrame(0.05, 1.0, 0.0)], disconnect_at_end=True
    )
    with Joystick(src, name="sim-stick", axis_ranges=src.ranges, deadband=0.05) as j:
        assert wait_until(lambda: j.failure is not None)
        assert j.latest().x == 1.0 and j.failure.port == "sim-stick"


def test_callable_source_follows_its_callable() -> None:
    state = {"x": 0.0}
    src = CallableJoystick(lambda: (state["x"], 0.0, ()), rate_hz=200.0)
    with Joystick(src, axis_ranges=src.ranges, deadband=0.0) as j:
        state["x"] = -0.75
        assert wait_until(lambda: abs(j.latest().x + 0.75) < 1e-4)
        src.stop.set()
        assert wait_until(lambda: j.finished)


# -- evdev ----------------------------------------------------------------------------------


def test_missing_evdev_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "evdev", None)  # import evdev -> ImportError
    with pytest.raises(SensorError, match="python-evdev is not installed") as err:
        open_evdev_joystick(JoystickConfig(device="/dev/input/event3"))
    assert err.value.port == "/dev/input/event3"


class PipeDevice:
    """Stands in for evdev.InputDevice: absinfo, a readable fd, and events written to a pipe."""

    EVENT = struct.Struct("<HHi")

    def __init__(self, path: str, axes: dict[int, tuple[int, int, int]]) -> None:
        self.path = path
        self.axes = axes
        self.fd, self._w = os.pipe()
        os.set_blocking(self.fd, False)
        self.closed = False

    def capabilities(self, absinfo: bool = True) -> dict:
        info = {c: SimpleNamespace(value=v, min=lo, max=hi) for c, (v, lo, hi) in self.axes.items()}
        return {EV_ABS: list(info.items())}

    def send(self, *events: tuple[int, int, int]) -> None:
        os.write(self._w, b"".join(self.EVENT.pack(*e) for e in events))

    def read(self) -> Iterator[SimpleNamespace]:
        data = os.read(self.fd, 4096)
        if not data:
            raise OSError(errno.ENODEV, "No such device")
        for i in range(0, len(data), self.EVENT.size):
            t, c, v = self.EVENT.unpack_from(data, i)
            yield SimpleNamespace(type=t, code=c, value=v)

    def active_keys(self) -> list[int]:
        return []

    def unplug(self) -> None:
        os.close(self._w)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            os.close(self.fd)


def test_evdev_adapter_discovers_reads_and_detects_unplug(monkeypatch: pytest.MonkeyPatch) -> None:
    mouse = PipeDevice("/dev/input/event1", {ABS_CODES["ABS_WHEEL"]: (0, 0, 10)})
    pad = PipeDevice("/dev/input/event2", {X: (512, 0, 1023), Y: (512, 0, 1023)})
    devices = {d.path: d for d in (mouse, pad)}
    fake = SimpleNamespace(list_devices=lambda: list(devices), InputDevice=devices.__getitem__)
    monkeypatch.setitem(sys.modules, "evdev", fake)
    j = open_evdev_joystick(JoystickConfig(deadband=0.0, invert_y=True))
    try:
        assert j.port_name == "/dev/input/event2" and mouse.closed
        assert j.latest().x == pytest.approx(0.0, abs=1e-3)  # initial absinfo value
        pad.send((EV_ABS, X, 1023), (EV_ABS, Y, 0), (EV_SYN, SYN_REPORT, 0))
        assert wait_until(lambda: j.latest().seq == 1)
        assert (j.latest().x, j.latest().y) == (1.0, 1.0)
        pad.unplug()
        assert wait_until(lambda: j.failure is not None)
        assert j.failure.port == "/dev/input/event2"
    finally:
        j.close()
        mouse.close()
    assert pad.closed
    with pytest.raises(SensorError, match="no input device has both ABS_RX and ABS_RY"):
        open_evdev_joystick(JoystickConfig(axis_x="ABS_RX", axis_y="ABS_RY"))


# -- property -------------------------------------------------------------------------------

events = st.tuples(
    st.sampled_from([EV_SYN, EV_KEY, EV_ABS, 2, 4, 0x15]),
    st.integers(0, 0x2FF),
    st.integers(-(2**31), 2**31 - 1),
)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.lists(events, max_size=40), st.floats(0, 0.99))
def test_property_random_events_keep_axes_in_range(evs: list, deadband: float) -> None:
    j = stick(deadband=deadband, resync=lambda: ({}, []))
    for e in evs:
        j.handle_event(*e)
    s = j.latest()
    assert -1.0 <= s.x <= 1.0 and -1.0 <= s.y <= 1.0
    assert all(-1.0 <= v <= 1.0 for v in s.axes.values())
    assert s.seq == j.stats.reports
