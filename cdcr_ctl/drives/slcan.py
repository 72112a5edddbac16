"""slcan (Lawicel ASCII) USB-CAN adapters with the frame path done a line (not a byte) at a time.

python-can's ``slcanBus`` reads the serial port one byte per system call (a ``select`` and a
``read`` per byte: one 1 kHz cycle of three TPDO lines and four transmit acknowledgements is
~60 of each per millisecond) and drains the port after every frame it writes (``tcdrain``: the
sender waits until the adapter has taken the line, on a pty until the other process has read
it). At 1 kHz that cannot keep up. :class:`SlcanBus` keeps python-can's set-up (serial port,
``Sn`` bit rate, ``O``/``L``/``C``, version query) and replaces the frame path:

- receive: one ``read`` takes whatever the port holds; complete lines (``\\r``; ``\\a`` BEL
  ends an error answer) are parsed from a buffer; the adapter's answers that are not frames
  (``z``/``Z`` transmit acknowledgements, an empty OK, BEL) are dropped without making a
  Message; filters whose masks are the full 11-bit identifier are one set lookup before any
  Message is made, others fall back to python-can's matching; frames for a hook
  (:meth:`SlcanBus.set_frame_hook`, the cyclic TPDOs) go to it as (id, bytes) at once;
- send: each line goes out with one ``write`` and no drain; :meth:`SlcanBus.send_frames`
  ((id, data) pairs) writes a burst (a cycle's set-points and SYNC) with one ``write``; a port
  that does not take the bytes within ``timeout`` raises :class:`can.CanTimeoutError` (a line
  already started is finished first, within :data:`PARTIAL_LINE_S`, so the adapter never sees two
  lines run together); the port's settings are never changed per call.

The bytes on the wire are the same as python-can's (``tiiildd..\\r``, hex upper case). Ports
without a file descriptor (pyserial URL handlers such as ``loop://``) use python-can's own path;
a TCP port (``socket://host:port``, a networked adapter) gets TCP_NODELAY.
"""

from __future__ import annotations

import collections
import contextlib
import os
import select
import socket
import stat
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import can
from can.interfaces.slcan import slcanBus
from can.util import CAN_FD_DLC, len2dlc

#: Bytes taken from the port per read (a burst of lines).
READ_SIZE = 4096
#: A partial line longer than this without its terminator is junk and dropped (characters).
MAX_LINE = 160
#: How long the rest of a line already partly written may take after the send timeout (s).
PARTIAL_LINE_S = 1.0
_STD_MASK = 0x7FF
#: First characters of frame lines (python-can's reader: ``x`` is CANdapter's extended frame).
_FRAME_KINDS = frozenset("tTrRdDbBx")
_STD_KINDS = frozenset("trdb")


def encode_line(msg: can.Message) -> bytes:
    """The slcan line (with ``\\r``) python-can's slcan interface sends for ``msg``."""
    if msg.is_remote_frame:
        if msg.is_extended_id:
            return f"R{msg.arbitration_id:08X}{msg.dlc:d}\r".encode()
        return f"r{msg.arbitration_id:03X}{msg.dlc:d}\r".encode()
    if msg.is_fd:
        fd_dlc = len2dlc(msg.dlc)
        kind = "B" if msg.bitrate_switch else "D"
        if not msg.is_extended_id:
            kind = kind.lower()
        ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
        return f"{kind}{ident}{fd_dlc:X}{msg.data.hex().upper()}\r".encode()
    if msg.is_extended_id:
        return f"T{msg.arbitration_id:08X}{msg.dlc:d}{msg.data.hex().upper()}\r".encode()
    return f"t{msg.arbitration_id:03X}{msg.dlc:d}{msg.data.hex().upper()}\r".encode()


def encode_data_line(can_id: int, data: bytes) -> bytes:
    """:func:`encode_line` of a standard data frame (11-bit ``can_id``, 0-8 bytes), without a
    Message."""
    return f"t{can_id:03X}{len(data)}{data.hex().upper()}\r".encode()


def parse_line(line: str, timestamp: float = 0.0) -> can.Message | None:
    """One received slcan line (no terminator) -> Message, as python-can's slcan interface reads
    it; None for the adapter's other answers and for malformed lines."""
    try:
        return _parse(line, timestamp)
    except (ValueError, IndexError, KeyError):
        return None


def _parse(line: str, timestamp: float) -> can.Message | None:
    kind = line[:1]
    ext = kind in ("T", "R", "x", "D", "B")
    fd = kind in ("d", "D", "b", "B")
    if kind in ("t", "r", "d", "b"):
        id_end = 4
    elif ext:
        id_end = 9
    else:
        return None  # z / Z acknowledgement, V/N/F answers, junk
    if len(line) <= id_end:
        return None
    can_id = int(line[1:id_end], 16)
    dlc = int(line[id_end], 16 if fd else 10)
    remote = kind in ("r", "R")
    data = None
    if not remote:
        n = CAN_FD_DLC[dlc] if fd else dlc
        hexdata = line[id_end + 1 : id_end + 1 + 2 * n]
        if len(hexdata) != 2 * n:
            return None
        data = bytearray.fromhex(hexdata)
    return can.Message(
        arbitration_id=can_id,
        is_extended_id=ext,
        timestamp=timestamp,
        is_remote_frame=remote,
        is_fd=fd,
        bitrate_switch=kind in ("b", "B"),
        dlc=CAN_FD_DLC[dlc] if fd else dlc,
        data=data,
    )


def _no_delay(fd: int) -> None:
    """A TCP port (``socket://``): send each write at once (no Nagle wait for an ACK)."""
    if not stat.S_ISSOCK(os.fstat(fd).st_mode):
        return
    sock = socket.socket(fileno=os.dup(fd))
    try:
        if sock.type == socket.SOCK_STREAM and sock.family in (socket.AF_INET, socket.AF_INET6):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    finally:
        sock.close()


class SlcanBus(slcanBus):
    """python-can's slcan interface with a line-at-a-time frame path (module docstring).

    Same constructor as :class:`can.interfaces.slcan.slcanBus`. :attr:`bad_lines` counts
    received lines that were neither a frame nor an adapter answer (garbled bytes); they are
    dropped, never raised.
    """

    def __init__(self, channel: Any, *args: Any, **kwargs: Any) -> None:
        self._fd: int | None = None
        self._poll: Any = None
        self._lines: collections.deque[str] = collections.deque()
        self._partial = ""
        self._accept: frozenset[int] | None = None
        self._generic_filters = False
        self._hook: Callable[[int, bytes, float], None] | None = None
        self._hook_ids: frozenset[int] = frozenset()
        self.bad_lines = 0
        # The device path, for canopen's "Connected to ..." line and the errors below
        # (python-can's slcan leaves BusABC's "unknown").
        self.channel_info = str(channel)
        super().__init__(channel, *args, **kwargs)
        try:
            fd = self.serialPortOrig.fileno()
        except Exception:  # a URL handler (loop://) has none: python-can's own path
            fd = None
        if isinstance(fd, int) and fd >= 0:
            _no_delay(fd)
            self._fd = fd
            self._poll = select.poll()
            self._poll.register(fd, select.POLLIN | select.POLLERR | select.POLLHUP)

    # ------------------------------------------------------------------ frame hook
    def set_frame_hook(
        self, can_ids: Iterable[int], hook: Callable[[int, bytes, float], None] | None
    ) -> None:
        """Standard data frames with these identifiers go to ``hook(can_id, data, timestamp)``
        in the receiving thread, as they are read: no Message, no filters, no listener chain
        (a 1 kHz cycle's TPDOs). :meth:`recv` does not return them. ``hook`` must not raise.
        ``None`` switches the hook off."""
        self._hook_ids = frozenset(can_ids) if hook is not None else frozenset()
        self._hook = hook

    # ------------------------------------------------------------------ filters
    def _apply_filters(self, filters: can.typechecking.CanFilters | None) -> None:
        """Standard-id filters with the full mask become one set; anything else is matched by
        python-can's :meth:`~can.BusABC._matches_filters` per Message."""
        self._accept, self._generic_filters = None, False
        if not filters:
            return
        if all(
            f.get("can_mask", 0) & _STD_MASK == _STD_MASK
            and f.get("extended") is False
            and f["can_id"] <= _STD_MASK
            for f in filters
        ):
            self._accept = frozenset(f["can_id"] for f in filters)
        else:
            self._generic_filters = True

    # ------------------------------------------------------------------ receive
    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._fd is None:
            return super()._recv_internal(timeout)
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            lines = self._lines
            while lines:
                msg = self._take(lines.popleft())
                if msg is not None:
                    return msg, True
            if deadline is None:
                wait_ms = None
            else:
                left = deadline - time.monotonic()
                if left < 0:
                    return None, True
                wait_ms = int(left * 1000.0) + 1 if left > 0 else 0
            try:
                events = self._poll.poll(wait_ms)
            except OSError as exc:
                raise can.CanOperationError(f"slcan {self.channel_info}: poll: {exc}") from exc
            if not events:
                if deadline is not None and time.monotonic() >= deadline:
                    return None, True
                continue
            try:
                chunk = os.read(self._fd, READ_SIZE)
            except BlockingIOError:
                continue
            except OSError as exc:
                raise can.CanOperationError(
                    f"slcan {self.channel_info}: could not read from serial device ({exc})"
                ) from exc
            if not chunk:
                raise can.CanOperationError(
                    f"slcan {self.channel_info}: device reports data but returned none "
                    "(disconnected?)"
                )
            self._split(chunk)

    def _split(self, chunk: bytes) -> None:
        text = self._partial + chunk.decode("ascii", "replace")
        if "\a" in text:
            text = text.replace("\a", "\r")
        if "\n" in text:
            text = text.replace("\n", "")
        parts = text.split("\r")
        rest = parts.pop()
        if len(rest) > MAX_LINE:
            self.bad_lines += 1
            rest = ""
        self._partial = rest
        self._lines.extend(p for p in parts if p)

    def _take(self, line: str) -> can.Message | None:
        """A received line -> Message if it is a frame that passes the filters (a frame for the
        hook goes there instead)."""
        kind = line[0]
        if kind not in _FRAME_KINDS:
            return None  # z/Z transmit acknowledgement, an answer to a command
        hook = self._hook
        if kind == "t" and hook is not None:
            try:
                can_id = int(line[1:4], 16)
                if can_id in self._hook_ids:
                    n = 2 * int(line[4])
                    hexdata = line[5 : 5 + n]
                    if len(hexdata) == n:
                        hook(can_id, bytes.fromhex(hexdata), time.time())
                        return None
            except (ValueError, IndexError):
                pass  # malformed: parse_line below says so
        accept = self._accept
        if accept is not None:
            if kind not in _STD_KINDS:
                return None  # extended: no standard-id filter takes it
            try:
                if int(line[1:4], 16) not in accept:
                    return None
            except ValueError:
                self.bad_lines += 1
                return None
        msg = parse_line(line, time.time())
        if msg is None:
            self.bad_lines += 1
            return None
        if self._generic_filters and not self._matches_filters(msg):
            return None
        return msg

    def shutdown(self) -> None:
        """python-can's shutdown (``C``, close the port); when the adapter is already gone
        (unplugged, its process died) the ``C`` cannot be written: the port is closed anyway."""
        try:
            super().shutdown()
        except can.CanError:
            with contextlib.suppress(Exception):
                self.serialPortOrig.close()

    # ------------------------------------------------------------------ send
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._fd is None:
            super().send(msg, timeout)
            return
        self._write_all(encode_line(msg), timeout)

    def send_frames(
        self, frames: Sequence[tuple[int, bytes]], timeout: float | None = None
    ) -> None:
        """Send standard data frames given as (11-bit id, data) in order with one write."""
        data = b"".join([encode_data_line(can_id, payload) for can_id, payload in frames])
        if self._fd is None:
            self.serialPortOrig.write(data)
            return
        self._write_all(data, timeout)

    def _write_all(self, data: bytes, timeout: float | None) -> None:
        fd = self._fd
        assert fd is not None
        try:
            n = os.write(fd, data)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            raise can.CanOperationError(
                f"slcan {self.channel_info}: could not write to serial device ({exc})"
            ) from exc
        if n < len(data):
            self._write_rest(data, n, timeout)

    def _write_rest(self, data: bytes, done: int, timeout: float | None) -> None:
        """The port's buffer is full: wait for room, at most ``timeout`` (then finish a line
        already started within PARTIAL_LINE_S and raise CanTimeoutError)."""
        fd = self._fd
        assert fd is not None
        deadline = None if timeout is None else time.monotonic() + timeout
        timed_out = False
        while done < len(data):
            if deadline is not None and time.monotonic() >= deadline and not timed_out:
                if done == 0 or data[done - 1] == 0x0D:
                    raise can.CanTimeoutError(
                        f"slcan {self.channel_info}: the adapter took no more bytes within "
                        f"{timeout} s"
                    )
                timed_out = True
                end = data.find(b"\r", done)
                data = data[: end + 1]  # finish this line only
                deadline = time.monotonic() + PARTIAL_LINE_S
            elif deadline is not None and time.monotonic() >= deadline:
                raise can.CanTimeoutError(f"slcan {self.channel_info}: a line was cut short")
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                select.select([], [fd], [], left)
                done += os.write(fd, data[done:])
            except BlockingIOError:
                continue
            except OSError as exc:
                raise can.CanOperationError(
                    f"slcan {self.channel_info}: could not write to serial device ({exc})"
                ) from exc
        if timed_out:
            raise can.CanTimeoutError(
                f"slcan {self.channel_info}: the adapter took no more bytes within {timeout} s"
            )


__all__ = ["SlcanBus", "encode_data_line", "encode_line", "parse_line"]
