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

:class:`NetworkJoystickServer` serves such a source as a *network joystick* on loopback: each
client that connects gets a fresh source (e.g. the paper's Fig. 12 stick session) streamed as
24-byte ``struct input_event`` records (:func:`cdcr_ctl.sensors.joystick.pack_input_event`), as
a netevent-style sender forwards a real device. :func:`load_stick_script` reads the scripts.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import select
import socket
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import yaml

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
    pack_input_event,
)

log = logging.getLogger(__name__)

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


# -- scripts --------------------------------------------------------------------------------


def load_stick_script(path: str | Path) -> list[JoystickFrame]:
    """A stick script from YAML: a list of ``{t_s, x, y, buttons}`` keyframes (times in s from
    the connection, axes in [-1, 1], buttons a list of evdev names), in time order.

    ValueError naming the file and the keyframe at fault.
    """
    path = Path(path)
    doc = yaml.safe_load(path.read_text())
    if not isinstance(doc, list) or not doc:
        raise ValueError(f"{path}: a stick script is a non-empty list of keyframes")
    frames: list[JoystickFrame] = []
    for i, item in enumerate(doc):
        if not isinstance(item, dict) or set(item) - {"t_s", "x", "y", "buttons"}:
            raise ValueError(f"{path}: [{i}]: keys are t_s, x, y, buttons: {item!r}")
        try:
            t, x, y = float(item["t_s"]), float(item.get("x", 0.0)), float(item.get("y", 0.0))
            buttons = frozenset(str(b) for b in item.get("buttons") or ())
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: [{i}]: {exc}: {item!r}") from exc
        if not (-1.0 <= x <= 1.0 and -1.0 <= y <= 1.0):
            raise ValueError(f"{path}: [{i}]: axes must be in [-1, 1]: {item!r}")
        unknown = sorted(b for b in buttons if b not in BUTTON_CODES)
        if unknown:
            raise ValueError(f"{path}: [{i}]: unknown button(s) {unknown}")
        frames.append(JoystickFrame(t, x, y, buttons))
    if [f.t_s for f in frames] != sorted(f.t_s for f in frames):
        raise ValueError(f"{path}: keyframes must be in time order")
    return frames


# -- network joystick -----------------------------------------------------------------------

#: Longest wait of the server's threads between checks of their stop flag (s).
SERVER_WAIT_S = 0.05


class NetworkJoystickServer:
    """A network joystick on ``host``:``port`` (loopback only): every client that connects gets
    ``source_factory()`` (an event source, e.g. a :class:`ScriptedJoystick`) streamed as
    ``struct input_event`` records, one TCP connection per client.

    When the source ends normally the connection stays open (a stick held still sends
    nothing) until the client leaves; an ``OSError`` from it (``disconnect_at_end``) closes the
    connection, as an unplugged sender does. ``hang_up()`` closes every connection now (fault
    injection). ``clients`` counts the connections served. ``port`` 0 picks a free port
    (:attr:`port` then says which).
    """

    def __init__(
        self,
        source_factory: Callable[[], Iterable[Event | None]],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        clock: Callable[[], float] = time.time,
    ) -> None:
        from cdcr_ctl.sim.tracker import require_loopback

        self.host = require_loopback(host)
        self.factory = source_factory
        self.clock = clock
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._conns: list[socket.socket] = []
        self._threads: list[threading.Thread] = []
        self.clients = 0
        self.records_sent = 0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.sock.bind((self.host, port))
            self.sock.listen(4)
        except OSError:
            self.sock.close()
            raise
        self.port: int = self.sock.getsockname()[1]
        self._accept = threading.Thread(target=self._accept_loop, name="sim-joystick", daemon=True)

    @property
    def url(self) -> str:
        """Where a controller connects: ``tcp://HOST:PORT``."""
        return f"tcp://{self.host}:{self.port}"

    def start(self) -> Self:
        self._accept.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self.sock.close()
        self.hang_up()
        self._accept.join(2.0)
        for t in list(self._threads):
            t.join(2.0)

    def hang_up(self) -> None:
        """Close every client connection (the sender goes away)."""
        with self._lock:
            conns, self._conns = self._conns, []
        for c in conns:
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
            c.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.sock], [], [], SERVER_WAIT_S)
                if not ready:
                    continue
                conn, peer = self.sock.accept()
            except (OSError, ValueError):
                return
            with self._lock:
                self._conns.append(conn)
                self.clients += 1
            log.info("sim joystick: client %s:%d connected", *peer[:2])
            t = threading.Thread(
                target=self._serve, args=(conn,), name="sim-joystick-client", daemon=True
            )
            self._threads = [x for x in self._threads if x.is_alive()] + [t]
            t.start()

    def _serve(self, conn: socket.socket) -> None:
        source: Any = self.factory()
        try:
            for event in source:
                if self._stop.is_set() or _peer_left(conn):
                    return
                if event is not None:
                    conn.sendall(pack_input_event(*event, t_s=self.clock()))
                    self.records_sent += 1
            # Script over: hold still (send nothing) until the client leaves or we stop.
            while not self._stop.is_set() and not _peer_left(conn, SERVER_WAIT_S):
                pass
        except OSError as exc:
            log.info("sim joystick: connection closed (%s)", exc)
        finally:
            stop = getattr(source, "stop", None)
            if stop is not None:
                stop.set()
            with self._lock:
                if conn in self._conns:
                    self._conns.remove(conn)
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
            conn.close()


def _peer_left(conn: socket.socket, wait_s: float = 0.0) -> bool:
    """True when the client closed its end (readable with no data) or the socket failed."""
    try:
        ready, _, _ = select.select([conn], [], [], wait_s)
        if not ready:
            return False
        return conn.recv(4096) == b""
    except (OSError, ValueError):
        return True
