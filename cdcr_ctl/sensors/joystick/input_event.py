"""``struct input_event`` records: pack one, decode a byte stream of them (pure bytes, no I/O)."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.joystick.codes import EV_MAX, Event

# -- network joystick: struct input_event over TCP ------------------------------------------

#: ``struct input_event`` of a 64-bit Linux (linux/input.h): struct timeval {int64 tv_sec,
#: int64 tv_usec}, uint16 type, uint16 code, int32 value; little endian, 24 bytes, no padding.
INPUT_EVENT = struct.Struct("<qqHHi")
INPUT_EVENT_SIZE = INPUT_EVENT.size  # 24


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
