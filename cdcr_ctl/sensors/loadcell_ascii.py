"""Continuous ASCII output of a weighing transmitter: one line per reading, one cell per port.

A line looks like ``ST,GS,+  4.876kg`` followed by CR LF. Parsed tolerantly:

- status ``ST`` (stable), ``US`` (unstable, in motion) or ``OL`` (overload); any letter case;
- ``GS`` (gross) or ``NT`` (net, tared), optional;
- sign ``+``/``-`` or none, spaces anywhere between fields and inside the padded number;
- value with or without decimals, or ``OL`` in place of the number (overload);
- unit ``kg``, ``g``, ``N``, ``lb``/``lbs`` (any case); kg and lb are kilogram-/pound-force;
- lines end in CR, LF or CR LF; empty lines are ignored.

Anything else (a line cut by a reconnect, line noise, an overlong run without a line end) is
counted in :class:`~cdcr_ctl.sensors.loadcell.LinkStats` and skipped, never returned. The format
has no checksum: a digit flipped by noise into another digit cannot be detected here.
"""

from __future__ import annotations

import contextlib
import math
import re
from collections.abc import Callable
from typing import TypeVar

import serial

from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.loadcell import LinkStats, LoadCellReading, TrafficLog, to_newtons

#: Longest line accepted (bytes, without its line end); a longer run is noise.
MAX_LINE_BYTES = 48

#: Longest single blocking read of the stream (s): the port's read timeout.
READ_POLL_S = 0.01

_UNITS = {b"kg": "kg", b"g": "g", b"n": "N", b"lb": "lb", b"lbs": "lb"}

_LINE = re.compile(
    rb"""\s*(?P<status>ST|US|OL)\s*,
         \s*(?:(?P<kind>GS|NT)\s*,\s*)?
         (?P<sign>[+-]?)\s*
         (?P<value>\d{1,9}(?:\.\d{0,9})?|\.\d{1,9}|OL)\s*
         (?P<unit>kg|g|n|lbs|lb)\s*""",
    re.IGNORECASE | re.VERBOSE,
)

R = TypeVar("R")


def parse_line(line: bytes) -> LoadCellReading | None:
    """One line (without its line end) as a reading in N, or None when it is not a valid line."""
    m = _LINE.fullmatch(line)
    if m is None:
        return None
    status = m["status"].upper()
    kind = m["kind"].upper() if m["kind"] else None
    negative = m["sign"] == b"-"
    unit = _UNITS[m["unit"].lower()]
    net = None if kind is None else kind == b"NT"
    if status == b"OL" or m["value"].upper() == b"OL":
        value = -math.inf if negative else math.inf
        return LoadCellReading(value, unit, value, stable=None, net=net, overload=True)
    value = float(m["value"])
    if negative:
        value = -value
    return LoadCellReading(value, unit, to_newtons(value, unit), stable=status == b"ST", net=net)


def format_line(
    value: float,
    unit: str = "kg",
    *,
    decimals: int = 3,
    width: int = 7,
    stable: bool = True,
    net: bool = False,
    overload: bool = False,
) -> bytes:
    """The line a transmitter sends for ``value`` in ``unit``, CR LF included.

    ``ST,GS,+  4.876kg``: status, gross/net, sign, the magnitude right-aligned in ``width``
    characters with ``decimals`` decimals, unit. Overload: ``OL,GS,+     OLkg``.
    """
    kind = "NT" if net else "GS"
    sign = "-" if value < 0 else "+"
    if overload:
        return f"OL,{kind},{sign}{'OL':>{width}}{unit}\r\n".encode("ascii")
    status = "ST" if stable else "US"
    return f"{status},{kind},{sign}{abs(value):{width}.{decimals}f}{unit}\r\n".encode("ascii")


class AsciiLineParser:
    """Incremental parser: feed it bytes in any chunks, get the readings of complete lines.

    ``stats`` counts good lines, bad lines and discarded bytes.
    """

    def __init__(self, stats: LinkStats | None = None) -> None:
        self.stats = stats if stats is not None else LinkStats()
        self._line = bytearray()
        self._skipping = False  # inside an overlong run: drop until the next line end

    def feed(self, data: bytes) -> list[LoadCellReading]:
        """Parse ``data``; return the readings of the lines it completed, oldest first."""
        out: list[LoadCellReading] = []
        for piece in re.split(rb"([\r\n])", bytes(data)):
            if piece in (b"\r", b"\n"):
                self._end_line(out)
            elif piece:
                self._extend(piece)
        return out

    def _extend(self, piece: bytes) -> None:
        if self._skipping:
            self.stats.discarded_bytes += len(piece)
            return
        self._line += piece
        if len(self._line) > MAX_LINE_BYTES:
            self.stats.bad_frames += 1
            self.stats.discarded_bytes += len(self._line)
            self._line.clear()
            self._skipping = True

    def _end_line(self, out: list[LoadCellReading]) -> None:
        if self._skipping:
            self._skipping = False
            return
        if not self._line:
            return
        reading = parse_line(bytes(self._line))
        if reading is None:
            self.stats.bad_frames += 1
            self.stats.discarded_bytes += len(self._line)
        else:
            self.stats.frames_ok += 1
            out.append(reading)
        self._line.clear()


class AsciiLoadCellStream:
    """One load cell streaming ASCII lines on an injected pyserial ``port``.

    ``port``'s read timeout is set to :data:`READ_POLL_S`; :meth:`close` closes it. ``port_name``
    names the port in errors (default ``port.port``).
    """

    n_cells = 1

    def __init__(self, port: serial.SerialBase, *, port_name: str | None = None) -> None:
        self.port = port
        self.port_name = port_name or str(getattr(port, "port", None) or port)
        self.stats = LinkStats()
        self.traffic = TrafficLog()
        self.parser = AsciiLineParser(self.stats)
        try:
            port.timeout = READ_POLL_S
        except (serial.SerialException, OSError, ValueError) as exc:
            raise SensorError(self.port_name, f"cannot configure port: {exc}") from exc

    def address(self, index: int) -> int | None:
        """An ASCII stream has no address."""
        return None

    def poll(self) -> list[tuple[int, LoadCellReading]]:
        """Read what arrived (waiting at most :data:`READ_POLL_S`); readings of complete lines.

        Raises :class:`SensorError` when the port fails (disconnect).
        """
        waiting = self._io("check", lambda: self.port.in_waiting)
        data = self._io("read", lambda: self.port.read(max(1, waiting)))
        if not data:
            return []
        self.traffic.add("rx", data)
        return [(0, r) for r in self.parser.feed(data)]

    def tare(self, index: int) -> None:
        """Not possible: the stream is one-way. Zero in software instead."""
        raise SensorError(self.port_name, "an ASCII stream is one-way: it cannot be tared")

    def close(self) -> None:
        """Close the port (idempotent)."""
        with contextlib.suppress(serial.SerialException, OSError):
            self.port.close()

    def _io(self, doing: str, call: Callable[[], R]) -> R:
        try:
            return call()
        except (serial.SerialException, OSError) as exc:
            raise SensorError(
                self.port_name,
                f"serial port failed during {doing} (disconnected?): {exc}\n"
                f"last data:\n{self.traffic.dump()}",
            ) from exc
