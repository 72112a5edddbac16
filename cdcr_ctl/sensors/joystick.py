"""Joystick through Linux evdev: normalised axes in [-1, 1] with a deadband, and buttons.

The reader consumes an *event source*: any iterable of ``(type, code, value)`` tuples in evdev's
terms (``EV_ABS`` axis moves, ``EV_KEY`` button presses, ``EV_SYN`` reports), which may also yield
``None`` as an idle tick (lets the thread notice ``stop()``). Tests and the simulated rig inject a
list or a scripted source (``cdcr_ctl.sim.joystick``); :func:`open_evdev_joystick` makes one from
a real device with python-evdev, an optional dependency (``pip install 'cdcr-ctl[joystick]'``)
imported only there. :func:`open_tcp_joystick` makes one from a *network joystick*: the kernel's
``struct input_event`` records of a device streamed over TCP (:class:`InputEventParser`), the way
netevent-style tools and ``socat -u /dev/input/eventN TCP-LISTEN:PORT`` forward input devices;
:func:`open_joystick` picks the transport from the config's ``device``.

State is published atomically at each ``SYN_REPORT`` (the kernel's end of a consistent set).
After ``SYN_DROPPED`` (the kernel's buffer overflowed) events are ignored up to the next report,
and the device's full state is re-read when a ``resync`` callable is given.

Normalisation of a raw axis value ``v`` with range [min, max] (from the device's absinfo):
``u = clip((v - c) / h, -1, 1)`` with ``c = (min + max) / 2``, ``h = (max - min) / 2``; then the
deadband ``d``: ``0`` when ``|u| <= d``, else ``sign(u) (|u| - d) / (1 - d)``, so the output is
continuous and still reaches ±1.
"""

from __future__ import annotations

import contextlib
import math
import select
import socket
import struct
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from cdcr_ctl.config.tracking import JoystickConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.polling import PollingReader
from cdcr_ctl.sensors.sample import Clock, LatestValue

#: Event types and codes of linux/input-event-codes.h (kernel ABI, fixed).
EV_SYN = 0x00
EV_KEY = 0x01
EV_ABS = 0x03
SYN_REPORT = 0
SYN_DROPPED = 3

#: Absolute-axis names -> codes (linux/input-event-codes.h).
ABS_CODES: Mapping[str, int] = MappingProxyType(
    {
        "ABS_X": 0x00,
        "ABS_Y": 0x01,
        "ABS_Z": 0x02,
        "ABS_RX": 0x03,
        "ABS_RY": 0x04,
        "ABS_RZ": 0x05,
        "ABS_THROTTLE": 0x06,
        "ABS_RUDDER": 0x07,
        "ABS_WHEEL": 0x08,
        "ABS_GAS": 0x09,
        "ABS_BRAKE": 0x0A,
        "ABS_HAT0X": 0x10,
        "ABS_HAT0Y": 0x11,
        "ABS_HAT1X": 0x12,
        "ABS_HAT1Y": 0x13,
    }
)
ABS_NAMES: Mapping[int, str] = MappingProxyType({v: k for k, v in ABS_CODES.items()})

#: Joystick and gamepad button codes -> names (linux/input-event-codes.h).
BUTTON_NAMES: Mapping[int, str] = MappingProxyType(
    {
        0x120: "BTN_TRIGGER",
        0x121: "BTN_THUMB",
        0x122: "BTN_THUMB2",
        0x123: "BTN_TOP",
        0x124: "BTN_TOP2",
        0x125: "BTN_PINKIE",
        0x126: "BTN_BASE",
        0x127: "BTN_BASE2",
        0x128: "BTN_BASE3",
        0x129: "BTN_BASE4",
        0x12A: "BTN_BASE5",
        0x12B: "BTN_BASE6",
        0x130: "BTN_SOUTH",
        0x131: "BTN_EAST",
        0x132: "BTN_C",
        0x133: "BTN_NORTH",
        0x134: "BTN_WEST",
        0x135: "BTN_Z",
        0x136: "BTN_TL",
        0x137: "BTN_TR",
        0x138: "BTN_TL2",
        0x139: "BTN_TR2",
        0x13A: "BTN_SELECT",
        0x13B: "BTN_START",
        0x13C: "BTN_MODE",
        0x13D: "BTN_THUMBL",
        0x13E: "BTN_THUMBR",
    }
)
BUTTON_CODES: Mapping[str, int] = MappingProxyType({v: k for k, v in BUTTON_NAMES.items()})

#: Longest wait of the evdev source for an event before yielding an idle tick (s).
EVDEV_POLL_S = 0.02
#: Highest event type of the kernel ABI (EV_MAX, linux/input-event-codes.h).
EV_MAX = 0x1F

Event = tuple[int, int, int]


def axis_code(name: str) -> int:
    """evdev code of an axis name (``"ABS_RY"``); ValueError naming the known ones otherwise."""
    try:
        return ABS_CODES[name]
    except KeyError:
        raise ValueError(f"unknown joystick axis {name!r} (know {', '.join(ABS_CODES)})") from None


def button_name(code: int) -> str:
    """Name of a button code (``BTN_SOUTH``), or ``KEY_<code>`` for other keys."""
    return BUTTON_NAMES.get(code, f"KEY_{code}")


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


# -- evdev ----------------------------------------------------------------------------------


def _import_evdev(device: str) -> Any:
    try:
        import evdev  # optional dependency: imported only when a real joystick is opened
    except ImportError as exc:
        raise SensorError(
            device,
            "python-evdev is not installed: pip install 'cdcr-ctl[joystick]' (or evdev)",
        ) from exc
    return evdev


def _abs_info(device: Any) -> dict[int, Any]:
    caps = device.capabilities(absinfo=True)
    return {code: info for code, info in caps.get(EV_ABS, [])}


def _find_device(evdev: Any, codes: tuple[int, int]) -> Any:
    for path in evdev.list_devices():
        try:
            dev = evdev.InputDevice(path)
        except OSError:
            continue
        if all(c in _abs_info(dev) for c in codes):
            return dev
        dev.close()
    return None


def _evdev_events(device: Any, name: str) -> Iterator[Event | None]:
    fd = device.fd
    while True:
        try:
            ready, _, _ = select.select([fd], [], [], EVDEV_POLL_S)
            if not ready:
                yield None
                continue
            for ev in device.read():
                yield (ev.type, ev.code, ev.value)
        except BlockingIOError:
            yield None
        except OSError as exc:
            raise SensorError(name, f"joystick disconnected: {exc}") from exc


def config_axis_range(cfg: JoystickConfig) -> AxisRange | None:
    """The steering axes' raw range given in the config (``axis_range``), or None."""
    if cfg.axis_range is None:
        return None
    return AxisRange(cfg.axis_range.min, cfg.axis_range.max)


def _config_ranges(cfg: JoystickConfig) -> dict[int, AxisRange]:
    """The steering axes' raw range from ``cfg.axis_range`` (empty when not given)."""
    r = config_axis_range(cfg)
    return {} if r is None else {axis_code(cfg.axis_x): r, axis_code(cfg.axis_y): r}


def open_evdev_joystick(
    cfg: JoystickConfig, *, clock: Clock = time.monotonic, start: bool = True
) -> Joystick:
    """Open the evdev device of ``cfg`` (or the first with both axes) and start a reader.

    Axis ranges come from the device's absinfo; ``cfg.axis_range``, when given, overrides
    them for the two steering axes. Raises :class:`SensorError` when python-evdev is missing,
    the device cannot be opened or lacks an axis; ValueError for an unknown axis name.
    """
    codes = (axis_code(cfg.axis_x), axis_code(cfg.axis_y))
    where = cfg.device or "evdev"
    evdev = _import_evdev(where)
    try:
        device = evdev.InputDevice(cfg.device) if cfg.device else _find_device(evdev, codes)
    except OSError as exc:
        raise SensorError(where, f"cannot open joystick: {exc}") from exc
    if device is None:
        raise SensorError(where, f"no input device has both {cfg.axis_x} and {cfg.axis_y}")
    name = str(getattr(device, "path", where))
    info = _abs_info(device)
    missing = [n for n, c in zip((cfg.axis_x, cfg.axis_y), codes, strict=True) if c not in info]
    if missing:
        device.close()
        raise SensorError(name, f"joystick has no axis {', '.join(missing)}")
    ranges = {c: AxisRange(i.min, i.max) for c, i in info.items() if i.max > i.min}
    ranges.update(_config_ranges(cfg))

    def resync() -> tuple[dict[int, int], list[int]]:
        now = _abs_info(device)
        return {c: i.value for c, i in now.items()}, list(device.active_keys())

    stick = Joystick(
        _evdev_events(device, name),
        name=name,
        axis_x=cfg.axis_x,
        axis_y=cfg.axis_y,
        axis_ranges=ranges,
        deadband=cfg.deadband,
        invert_x=cfg.invert_x,
        invert_y=cfg.invert_y,
        initial={c: i.value for c, i in info.items()},
        resync=resync,
        closer=device.close,
        clock=clock,
    )
    return stick.start() if start else stick


# -- network joystick: struct input_event over TCP ------------------------------------------

#: ``struct input_event`` of a 64-bit Linux (linux/input.h): struct timeval {int64 tv_sec,
#: int64 tv_usec}, uint16 type, uint16 code, int32 value; little endian, 24 bytes, no padding.
INPUT_EVENT = struct.Struct("<qqHHi")
INPUT_EVENT_SIZE = INPUT_EVENT.size  # 24
#: How long the TCP source waits for bytes before yielding an idle tick (s).
TCP_POLL_S = 0.02
#: TCP keep-alive of the network joystick: probes after this much silence (s), this often (s),
#: this many unanswered probes = the sender is gone. A joystick held still sends nothing, so
#: silence alone never means a disconnect; the kernel's probes tell a dead peer (cable pulled,
#: host down) from a quiet one within ~idle + interval * count seconds.
TCP_KEEPIDLE_S = 1
TCP_KEEPINTVL_S = 1
TCP_KEEPCNT = 3


@dataclass(frozen=True, slots=True)
class InputEvent:
    """One decoded ``struct input_event``: the sender's timestamp (s, us), type, code, value."""

    sec: int
    usec: int
    type: int
    code: int
    value: int

    @property
    def event(self) -> Event:
        """As the reader takes it: ``(type, code, value)``."""
        return (self.type, self.code, self.value)


def pack_input_event(type_: int, code: int, value: int, t_s: float = 0.0) -> bytes:
    """The 24-byte record of one event at time ``t_s`` (s, sender clock), as the kernel writes
    it to a reader of ``/dev/input/eventN`` on a 64-bit machine."""
    sec = math.floor(t_s)
    usec = min(999_999, round((t_s - sec) * 1e6))
    return INPUT_EVENT.pack(sec, usec, type_, code, value)


class InputEventError(SensorError):
    """The byte stream is not a sequence of ``struct input_event`` records; ``offset`` is the
    byte offset (from the start of the stream) of the record at fault."""

    def __init__(self, port: str, offset: int, message: str) -> None:
        self.offset = offset
        super().__init__(port, f"byte {offset}: {message}")


class InputEventParser:
    """Incremental decoder of a stream of 24-byte ``struct input_event`` records.

    :meth:`feed` takes bytes as they arrive (records may be split anywhere across calls) and
    returns the complete records; the rest waits for the next call. A record that cannot be an
    input event (type above :data:`EV_MAX`, microseconds outside 0..999999, negative seconds)
    raises :class:`InputEventError` naming its byte offset: the stream has no sync marks, so
    after such a record nothing that follows can be trusted and the parser stays failed. The
    good records before it in the same call are returned first and the error is raised by the
    next call (:meth:`check`, :meth:`feed` or :meth:`eof`), so no good event is lost.
    :meth:`eof` checks that the stream ended on a record boundary.
    """

    def __init__(self, port: str = "joystick") -> None:
        self.port = port
        #: Bytes taken in so far; the offset of the next record is ``offset - len(pending)``.
        self.offset = 0
        self.records = 0
        self._buf = bytearray()
        self._failed: InputEventError | None = None

    @property
    def pending(self) -> int:
        """Bytes of an incomplete record waiting for the rest."""
        return len(self._buf)

    def check(self) -> None:
        """Raise the :class:`InputEventError` of a bad record seen so far, if any."""
        if self._failed is not None:
            raise self._failed

    def feed(self, data: bytes) -> list[InputEvent]:
        """Decode what ``data`` completes; :class:`InputEventError` on a bad record (see the
        class docstring for the records before it)."""
        self.check()
        self._buf += data
        self.offset += len(data)
        n = len(self._buf) // INPUT_EVENT_SIZE
        out: list[InputEvent] = []
        base = self.offset - len(self._buf)
        for i in range(n):
            sec, usec, type_, code, value = INPUT_EVENT.unpack_from(self._buf, i * INPUT_EVENT_SIZE)
            problem = ""
            if type_ > EV_MAX:
                problem = f"event type 0x{type_:04x} above EV_MAX (0x{EV_MAX:02x})"
            elif not 0 <= usec <= 999_999:
                problem = f"tv_usec {usec} outside 0..999999"
            elif sec < 0:
                problem = f"tv_sec {sec} negative"
            if problem:
                self._failed = InputEventError(
                    self.port,
                    base + i * INPUT_EVENT_SIZE,
                    f"not a struct input_event record ({problem}; 24-byte records of a 64-bit"
                    " kernel expected)",
                )
                del self._buf[:]
                self.records += len(out)
                if out:
                    return out
                raise self._failed
            out.append(InputEvent(sec, usec, type_, code, value))
        del self._buf[: n * INPUT_EVENT_SIZE]
        self.records += n
        return out

    def eof(self) -> None:
        """The stream ended: :class:`InputEventError` if it stopped inside a record."""
        self.check()
        if self._buf:
            raise InputEventError(
                self.port,
                self.offset - len(self._buf),
                f"stream ended {len(self._buf)} byte(s) into a {INPUT_EVENT_SIZE}-byte record",
            )


def _tcp_events(
    sock: socket.socket, name: str, poll_s: float = TCP_POLL_S
) -> Iterator[Event | None]:
    """Event source over a connected socket: records -> events, ``None`` while idle.

    The peer closing the connection, a reset, keep-alive failure or a bad record raise
    :class:`SensorError` (the device is gone: a network joystick does not end normally).
    """
    parser = InputEventParser(name)
    while True:
        try:
            ready, _, _ = select.select([sock], [], [], poll_s)
            if not ready:
                yield None
                continue
            data = sock.recv(INPUT_EVENT_SIZE * 256)
        except (OSError, ValueError) as exc:  # ValueError: select on a closed socket
            raise SensorError(name, f"joystick disconnected: {exc}") from exc
        if not data:
            parser.eof()
            raise SensorError(
                name,
                f"joystick disconnected: the sender closed the connection at byte {parser.offset}",
            )
        for ev in parser.feed(data):
            yield ev.event
        parser.check()


def _keepalive(sock: socket.socket) -> None:
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for opt, value in (
        ("TCP_KEEPIDLE", TCP_KEEPIDLE_S),
        ("TCP_KEEPINTVL", TCP_KEEPINTVL_S),
        ("TCP_KEEPCNT", TCP_KEEPCNT),
    ):
        if hasattr(socket, opt):  # Linux
            sock.setsockopt(socket.IPPROTO_TCP, getattr(socket, opt), value)


def open_tcp_joystick(
    cfg: JoystickConfig,
    *,
    clock: Clock = time.monotonic,
    start: bool = True,
    sock: socket.socket | None = None,
) -> Joystick:
    """Connect to the network joystick ``cfg.device`` (``tcp://HOST:PORT``) and start a reader.

    The sender streams ``struct input_event`` records (:data:`INPUT_EVENT`) of its device. There
    is no absinfo over the wire: the steering axes' raw range is ``cfg.axis_range`` (default
    signed 16 bit, :data:`DEFAULT_RANGE`) and the axes read 0 until their first event. ``sock``:
    an already connected socket (tests); else one is connected within ``cfg.connect_timeout_s``.
    Raises :class:`SensorError` naming the address when nobody answers there.
    """
    address = cfg.tcp_address
    if address is None:
        raise ValueError(f"not a network joystick: {cfg.device!r}")
    name = str(cfg.device)
    if sock is None:
        try:
            sock = socket.create_connection(address, timeout=cfg.connect_timeout_s)
        except OSError as exc:
            raise SensorError(name, f"cannot connect to the network joystick: {exc}") from exc
    try:
        sock.settimeout(None)
        sock.setblocking(True)
        _keepalive(sock)
        stick = Joystick(
            _tcp_events(sock, name),
            name=name,
            axis_x=cfg.axis_x,
            axis_y=cfg.axis_y,
            axis_ranges=_config_ranges(cfg),
            deadband=cfg.deadband,
            invert_x=cfg.invert_x,
            invert_y=cfg.invert_y,
            closer=sock.close,
            clock=clock,
        )
    except BaseException:
        sock.close()
        raise
    return stick.start() if start else stick


def open_joystick(
    cfg: JoystickConfig, *, clock: Clock = time.monotonic, start: bool = True
) -> Joystick:
    """The joystick of ``cfg``: a network joystick for ``tcp://`` devices, evdev otherwise."""
    if cfg.tcp_address is not None:
        return open_tcp_joystick(cfg, clock=clock, start=start)
    return open_evdev_joystick(cfg, clock=clock, start=start)
