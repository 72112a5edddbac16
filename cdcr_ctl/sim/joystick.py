"""Simulated joysticks: event sources for :class:`cdcr_ctl.sensors.joystick.Joystick`.

Both produce evdev-style ``(type, code, value)`` events followed by ``SYN_REPORT``, only for what
changed, and ``None`` idle ticks while waiting (so the reader's thread can stop promptly):

- :class:`ScriptedJoystick` plays a list of keyframes (time, x, y, pressed buttons) at their
  times (or at once with ``realtime=False``); ``disconnect_at_end`` raises an ``OSError`` like an
  unplugged device after the last one.
- :class:`CallableJoystick` samples a callable (x, y, buttons) at a fixed rate, for an
  interactive simulated rig.

Axis values are given normalised in [-1, 1] and sent as raw values over ``axis_range``
(:meth:`AxisRange.raw`); the reader needs the same range (:attr:`ranges`).
"""

from __future__ import annotations

import errno
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

from cdcr_ctl.sensors.joystick import (
    BUTTON_CODES,
    DEFAULT_RANGE,
    EV_ABS,
    EV_KEY,
    EV_SYN,
    SYN_REPORT,
    AxisRange,
    Event,
    axis_code,
)

#: Longest wait between idle ticks (s).
IDLE_TICK_S = 0.02


@dataclass(frozen=True, slots=True)
class JoystickFrame:
    """A joystick state at ``t_s`` (s from the script's start): axes in [-1, 1], pressed buttons
    by name (``BTN_SOUTH``, ``BTN_TRIGGER``, ...)."""

    t_s: float
    x: float = 0.0
    y: float = 0.0
    buttons: frozenset[str] = frozenset()


class _Encoder:
    """Turns successive states into the events that describe the change."""

    def __init__(self, axis_x: str, axis_y: str, axis_range: AxisRange) -> None:
        self.code_x, self.code_y = axis_code(axis_x), axis_code(axis_y)
        self.range = axis_range
        self._raw: dict[int, int] = {}
        self._pressed: frozenset[str] = frozenset()

    def events(self, x: float, y: float, buttons: Iterable[str]) -> list[Event]:
        out: list[Event] = []
        for code, value in ((self.code_x, x), (self.code_y, y)):
            raw = self.range.raw(value)
            if self._raw.get(code) != raw:
                self._raw[code] = raw
                out.append((EV_ABS, code, raw))
        pressed = frozenset(buttons)
        for name in sorted(pressed ^ self._pressed):
            try:
                code = BUTTON_CODES[name]
            except KeyError:
                raise ValueError(f"unknown button {name!r}") from None
            out.append((EV_KEY, code, 1 if name in pressed else 0))
        self._pressed = pressed
        if out:
            out.append((EV_SYN, SYN_REPORT, 0))
        return out


class ScriptedJoystick:
    """Plays ``script`` (keyframes in time order) as an event source; iterate it once.

    ``realtime``: wait until each keyframe's time (``clock``/``sleep`` injectable) and yield idle
    ticks meanwhile; False: yield everything at once. ``stop``: set it to end the iteration early.
    """

    def __init__(
        self,
        script: Sequence[JoystickFrame],
        *,
        axis_x: str = "ABS_X",
        axis_y: str = "ABS_Y",
        axis_range: AxisRange = DEFAULT_RANGE,
        realtime: bool = True,
        disconnect_at_end: bool = False,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        times = [f.t_s for f in script]
        if times != sorted(times):
            raise ValueError("joystick script keyframes must be in time order")
        self.script = list(script)
        self.encoder = _Encoder(axis_x, axis_y, axis_range)
        self.ranges = {self.encoder.code_x: axis_range, self.encoder.code_y: axis_range}
        self.realtime = realtime
        self.disconnect_at_end = disconnect_at_end
        self.clock = clock
        self.sleep = sleep
        self.stop = threading.Event()

    def __iter__(self) -> Iterator[Event | None]:
        t0 = self.clock()
        for frame in self.script:
            while self.realtime and not self.stop.is_set():
                left = t0 + frame.t_s - self.clock()
                if left <= 0:
                    break
                self.sleep(min(left, IDLE_TICK_S))
                yield None
            if self.stop.is_set():
                return
            yield from self.encoder.events(frame.x, frame.y, frame.buttons)
        if self.disconnect_at_end:
            raise OSError(errno.ENODEV, "No such device (simulated unplug)")


class CallableJoystick:
    """Samples ``state()`` -> (x, y, pressed button names) at ``rate_hz`` as an event source.

    Runs until :attr:`stop` is set. Only changes produce events; idle ticks otherwise.
    """

    def __init__(
        self,
        state: Callable[[], tuple[float, float, Iterable[str]]],
        *,
        rate_hz: float = 100.0,
        axis_x: str = "ABS_X",
        axis_y: str = "ABS_Y",
        axis_range: AxisRange = DEFAULT_RANGE,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if not rate_hz > 0:
            raise ValueError("rate_hz must be > 0")
        self.state = state
        self.period_s = 1.0 / rate_hz
        self.encoder = _Encoder(axis_x, axis_y, axis_range)
        self.ranges = {self.encoder.code_x: axis_range, self.encoder.code_y: axis_range}
        self.sleep = sleep
        self.stop = threading.Event()

    def __iter__(self) -> Iterator[Event | None]:
        while not self.stop.is_set():
            x, y, buttons = self.state()
            events = self.encoder.events(x, y, buttons)
            yield from events
            if not events:
                yield None
            self.sleep(self.period_s)
