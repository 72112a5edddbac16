"""Joystick reader: an event source in, the latest normalised state out (axes in [-1, 1], buttons).

The reader consumes an *event source*: any iterable of ``(type, code, value)`` tuples in evdev's
terms (``EV_ABS`` axis moves, ``EV_KEY`` button presses, ``EV_SYN`` reports), which may also yield
``None`` as an idle tick (lets the thread notice ``stop()``). State is published atomically at each
``SYN_REPORT``; after ``SYN_DROPPED`` events are ignored up to the next report, and the device's
full state is re-read when a ``resync`` callable is given.

Normalisation of a raw axis value ``v`` with range [min, max] (from the device's absinfo):
``u = clip((v - c) / h, -1, 1)`` with ``c = (min + max) / 2``, ``h = (max - min) / 2``; then the
deadband ``d``: ``0`` when ``|u| <= d``, else ``sign(u) (|u| - d) / (1 - d)``, so the output is
continuous and still reaches ±1.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from cdcr_ctl.config.tracking import JoystickConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.joystick.codes import (
    ABS_NAMES,
    EV_ABS,
    EV_KEY,
    EV_SYN,
    SYN_DROPPED,
    SYN_REPORT,
    Event,
    axis_code,
    button_name,
)
from cdcr_ctl.sensors.polling import PollingReader
from cdcr_ctl.sensors.sample import Clock, LatestValue


@dataclass(frozen=True, slots=True)
class AxisRange:
    """Raw range of an axis (device units), as evdev's absinfo reports it."""

    minimum: int
    maximum: int

    def __post_init__(self) -> None:
        if self.maximum <= self.minimum:
            raise ValueError(f"axis range needs maximum > minimum, got {self}")

    def normalise(self, value: int, deadband: float = 0.0) -> float:
        """Raw ``value`` -> [-1, 1] with ``deadband`` (see the module docstring)."""
        half = (self.maximum - self.minimum) / 2.0
        u = (value - (self.maximum + self.minimum) / 2.0) / half
        u = max(-1.0, min(1.0, u))
        if abs(u) <= deadband:
            return 0.0
        return math.copysign((abs(u) - deadband) / (1.0 - deadband), u)

    def raw(self, normalised: float) -> int:
        """Inverse without deadband: the raw value for ``normalised`` in [-1, 1]."""
        u = max(-1.0, min(1.0, normalised))
        half = (self.maximum - self.minimum) / 2.0
        return max(
            self.minimum,
            min(self.maximum, round((self.maximum + self.minimum) / 2.0 + u * half)),
        )


#: Range assumed for an axis the device did not describe (signed 16 bit, common for sticks).
DEFAULT_RANGE = AxisRange(-32768, 32767)


@dataclass(frozen=True, slots=True)
class JoystickState:
    """The loop's view of the joystick.

    ``x``, ``y``: the two steering axes in [-1, 1] after deadband and inversion (0 before the
    first report). ``axes``: every axis seen, normalised (by name, no inversion). ``buttons``:
    names of pressed buttons. ``t_s``: time of the last report (s, reader clock; NaN before the
    first), ``age_s``: now - t_s (inf before). ``seq``: reports so far. ``connected``: False once
    the device failed (the state is then frozen: do not steer with it).
    """

    x: float
    y: float
    axes: Mapping[str, float]
    buttons: frozenset[str]
    t_s: float
    age_s: float
    seq: int
    connected: bool


@dataclass
class JoystickStats:
    """Counters: ``events`` taken in, ``reports`` published, ``dropped`` SYN_DROPPED seen,
    ``ignored`` events of other types or discarded after a drop."""

    events: int = 0
    reports: int = 0
    dropped: int = 0
    ignored: int = 0


@dataclass(frozen=True, slots=True)
class _Snapshot:
    x: float
    y: float
    axes: Mapping[str, float] = field(default_factory=dict)
    buttons: frozenset[str] = frozenset()


class Joystick(PollingReader):
    """Reads an event source in a thread and keeps the latest normalised joystick state.

    ``events``: iterable of ``(type, code, value)`` or ``None`` ticks (see the module
    docstring); an ``OSError`` or :class:`SensorError` from it means the device is gone. The
    source ending is not a failure (a finished script): :attr:`finished` becomes True.
    ``name``: the device, named in errors. ``axis_x``/``axis_y``: axis names of the steering
    axes. ``axis_ranges``: raw range per axis code (others: :data:`DEFAULT_RANGE`).
    ``deadband``: fraction of the half range (0 <= d < 1). ``initial``: raw axis values before
    the first event (from absinfo). ``resync``: returns ``(raw axis values, pressed button codes)``
    read from the device after SYN_DROPPED. ``closer``: closes the device.
    """

    def __init__(
        self,
        events: Iterable[Event | None],
        *,
        name: str = "joystick",
        axis_x: str = "ABS_X",
        axis_y: str = "ABS_Y",
        axis_ranges: Mapping[int, AxisRange] | None = None,
        deadband: float = 0.05,
        invert_x: bool = False,
        invert_y: bool = False,
        initial: Mapping[int, int] | None = None,
        resync: Callable[[], tuple[Mapping[int, int], Iterable[int]]] | None = None,
        closer: Callable[[], None] | None = None,
        clock: Clock = time.monotonic,
    ) -> None:
        super().__init__()
        if not 0 <= deadband < 1:
            raise ValueError(f"deadband must be in [0, 1), got {deadband}")
        self.port_name = name
        self.code_x = axis_code(axis_x)
        self.code_y = axis_code(axis_y)
        self.ranges = dict(axis_ranges or {})
        self.deadband = float(deadband)
        self.sign_x = -1.0 if invert_x else 1.0
        self.sign_y = -1.0 if invert_y else 1.0
        self.clock = clock
        self.stats = JoystickStats()
        self.finished = False
        self._events: Iterator[Event | None] = iter(events)
        self._resync = resync
        self._closer = closer
        self._raw: dict[int, int] = dict(initial or {})
        self._pressed: set[int] = set()
        self._dropping = False
        # Not stale-checked: a joystick sends nothing while held still.
        self.values: LatestValue[_Snapshot] = LatestValue(math.inf, clock)
        self._initial = self.snapshot()  # what latest() shows before the first report

    # -- state machine ----------------------------------------------------------------------

    def handle_event(self, type_: int, code: int, value: int, t_s: float | None = None) -> bool:
        """Apply one event; True when it completed a report (state published)."""
        self.stats.events += 1
        if type_ == EV_SYN:
            if code == SYN_DROPPED:
                self.stats.dropped += 1
                self._dropping = True
                return False
            if code != SYN_REPORT:
                self.stats.ignored += 1
                return False
            if self._dropping:
                self._dropping = False
                if self._resync is not None:
                    raw, pressed = self._resync()
                    self._raw.update(raw)
                    self._pressed = set(pressed)
            self._publish(self.clock() if t_s is None else t_s)
            return True
        if self._dropping:
            self.stats.ignored += 1
        elif type_ == EV_ABS:
            self._raw[code] = int(value)
        elif type_ == EV_KEY:
            if value:  # 1 press, 2 autorepeat
                self._pressed.add(code)
            else:
                self._pressed.discard(code)
        else:
            self.stats.ignored += 1
        return False

    def snapshot(self) -> _Snapshot:
        """Normalised state from the raw values now (without publishing)."""
        axes = {
            ABS_NAMES.get(code, f"ABS_{code}"): self._range(code).normalise(raw, self.deadband)
            for code, raw in self._raw.items()
        }
        x = self._axis(self.code_x) * self.sign_x
        y = self._axis(self.code_y) * self.sign_y
        return _Snapshot(x, y, MappingProxyType(axes), frozenset(map(button_name, self._pressed)))

    def _axis(self, code: int) -> float:
        raw = self._raw.get(code)
        return 0.0 if raw is None else self._range(code).normalise(raw, self.deadband)

    def _range(self, code: int) -> AxisRange:
        return self.ranges.get(code, DEFAULT_RANGE)

    def _publish(self, t_s: float) -> None:
        self.values.publish(self.snapshot(), t_s)
        self.stats.reports += 1

    # -- reader -----------------------------------------------------------------------------

    def poll(self) -> None:
        """Take one event (or idle tick) from the source; SensorError when the device is gone."""
        try:
            event = next(self._events)
            if event is not None:
                self.handle_event(*event)  # may re-read the device (resync)
        except StopIteration:
            self.finished = True
            self._stop_event.set()
        except SensorError:
            raise
        except OSError as exc:
            raise SensorError(self.port_name, f"joystick disconnected: {exc}") from exc

    def latest(self, now_s: float | None = None) -> JoystickState:
        """Newest state aged at ``now_s`` (s; default now). Never blocks."""
        got = self.values.latest(now_s)
        s = got.value
        connected = self.failure is None
        if s is None:
            s = self._initial
        return JoystickState(s.x, s.y, s.axes, s.buttons, got.t_s, got.age_s, got.seq, connected)

    def _close_transport(self) -> None:
        if self._closer is not None:
            with contextlib.suppress(OSError):
                self._closer()


def config_axis_range(cfg: JoystickConfig) -> AxisRange | None:
    """The steering axes' raw range given in the config (``axis_range``), or None."""
    if cfg.axis_range is None:
        return None
    return AxisRange(cfg.axis_range.min, cfg.axis_range.max)


def _config_ranges(cfg: JoystickConfig) -> dict[int, AxisRange]:
    """The steering axes' raw range from ``cfg.axis_range`` (empty when not given)."""
    r = config_axis_range(cfg)
    return {} if r is None else {axis_code(cfg.axis_x): r, axis_code(cfg.axis_y): r}
