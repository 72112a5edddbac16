"""The shared-memory rings between the loop's process and the run-log writer process: their
layout and both sides' access without numpy (the writer process maps them with :class:`RingMap`
and never imports numpy: its start costs no numpy import; the producer's numpy views and batch
stores are :class:`~cdcr_ctl.runlog.writer.ring.SharedRing`'s).

One anonymous shared mapping (``memfd_create``, handed to the writer process as a file
descriptor: no name in ``/dev/shm``, nothing left behind when both processes end) holds

- a header of :data:`HEADER_SLOTS` int64 counters and flags (:data:`ROW_HEAD` ...),
- two text areas of :data:`TEXT_BYTES` (the close request, the write error) and one of
  :data:`NAMES_BYTES` (the names of the values of a row in the loop's own order, see below),
- the row ring: ``rows`` slots of ``n_numbers + 2`` float64 and ``rows`` text fields of
  :data:`EVENT_BYTES`. A slot is ``[order, text length, values...]``: order 0 means the values
  are the numeric columns in column order; order 1 means they are in the order named in the
  names area (``t_s``, ``cycle``, ``lateness_us``, then the loop's flat array) with ``t_s`` and
  the lateness as the loop has them (s, unrounded), so the loop copies its array in one piece
  and the writer process rounds those two as the loop's row does
  (:func:`~cdcr_ctl.runlog.columns.t_cell`, :func:`~cdcr_ctl.runlog.columns.lateness_cell_us`)
  and puts the numbers in column order,
- the CAN ring: ``frames`` records of :data:`CAN_RECORD` (timestamp s, arbitration id, flags,
  dlc, data length, 64 data bytes).

Each ring has one producer and one consumer. The producer fills slot ``head % capacity`` and then
stores ``head + 1`` in the header; the consumer reads the slots up to the head it loaded and then
stores its tail. A slot is reused only once the tail has passed it, so neither side ever sees a
half-written slot. The counters are aligned 8-byte stores, single instructions on x86-64 and
AArch64, and x86-64 keeps stores in program order; on a weaker memory model the Python
interpreter's own locking between the two stores orders them in practice.

Nothing here formats text or takes a lock on the loop's path: a row is one ``struct`` store of its
five head fields and one memoryview slice store of the loop's array (no numpy indexing, no
rounding): 0.75 us a row with warm caches, against 1.8 us with numpy stores and the rounding before,
and 0.06 us for the thread writer's ``deque.append`` (``git show
4f9c215:benchmarks/bench_runlog_write.py``; in the 1 kHz loop, after its sleep, about 4 us against
0.8 us). CAN frames are stored a batch at a time (:meth:`SharedRing.put_frames`, one numpy store of
a list of records): 0.6 us a frame in batches of 64 against 2.1 us a frame one at a time (same
benchmark).
"""

from __future__ import annotations

import contextlib
import json
import mmap
import os
import struct
from dataclasses import dataclass
from typing import Any

#: Header slots (int64). The slots the producer (the loop's process) writes share the first
#: 64-byte cache line, those the writer process writes start at the second: the loop's store of
#: ``ROW_HEAD`` every row never finds its line taken away by the writer's stores of its tail and
#: counters at every drain (false sharing between the two processes' cores).
HEADER_SLOTS = 64
ROW_HEAD = 0  # rows published by the producer (loop)
CAN_HEAD = 1
CLOSE = 2  # 1: the producer asks the writer to close (text in the close area)
ROW_DROPPED = 3  # rows the producer refused (ring full, closing, failed)
CAN_DROPPED = 4  # CAN frames the producer refused (ring full)
ROW_WAITS = 5  # rows the producer had to wait for room for (back-pressure, lock-step only)
ROW_TAIL = 8  # rows taken by the consumer (writer process)
CAN_TAIL = 9
FAILED = 10  # 1: the writer failed (text in the failure area)
DONE = 11  # 1: the writer process has closed the run (run.yaml written)
W_WRITTEN = 12  # the writer's counters, published at every drain
W_LOST = 13
W_FSYNCS = 14
W_BYTES = 15
W_DROPPED = 16
READY = 17  # 1: the writer process has opened its files
W_HIGH = 18  # high-water mark: most rows the ring held at a drain after the first
W_START = 19  # rows the ring held at the writer's first drain (its start-up: files, imports)
#: Bytes of each text area (close request, write error).
TEXT_BYTES = 4096
#: Bytes of a row's text (the ``event`` column); longer text is cut and marked.
EVENT_BYTES = 1024
#: Mark appended to a cut event text.
CUT_MARK = " [cut]"
#: A CAN frame record: timestamp (s), arbitration id, flags (bit 0 extended, 1 rx, 2 error,
#: 3 remote), dlc, data length, data (up to 64 bytes, CAN FD), one byte of padding.
CAN_RECORD = struct.Struct("<dIBBB64sx")

_HEADER_BYTES = HEADER_SLOTS * 8
_CLOSE_TEXT = _HEADER_BYTES
_FAIL_TEXT = _CLOSE_TEXT + TEXT_BYTES
#: Bytes of the names area (JSON list of names; a 3-segment, 12-cable rig needs ~1.3 kB).
NAMES_BYTES = 16384
_NAMES_TEXT = _FAIL_TEXT + TEXT_BYTES
_ROWS = _NAMES_TEXT + NAMES_BYTES
#: Byte offset of the first row slot.
ROWS_OFFSET = _ROWS
#: Float64 fields of a slot before its values: order, text length.
SLOT_HEAD = 2
#: Order of a slot's values: the numeric columns in column order / the names area's order
#: (``t_s`` and lateness in s, unrounded: the writer process rounds them).
ORDER_COLUMNS = 0.0
ORDER_NAMES = 1.0


def publish_writer_counts(hdr: Any, stats: Any, dropped: int) -> None:
    """Writer: its writer's counters (a :class:`~cdcr_ctl.runlog.writer.files.LogStats`) into
    the header ``hdr``, ``dropped`` as the rows dropped; read back by :func:`writer_counts`."""
    hdr[W_WRITTEN], hdr[W_LOST], hdr[W_FSYNCS], hdr[W_BYTES] = (
        stats.written,
        stats.lost,
        stats.fsyncs,
        stats.bytes,
    )
    hdr[W_DROPPED] = dropped


def writer_counts(hdr: Any) -> tuple[int, int, int, int, int]:
    """Producer: the writer's counters in the header ``hdr`` (or a copy of it): rows written,
    dropped, lost, fsyncs, bytes."""
    return (
        int(hdr[W_WRITTEN]),
        int(hdr[W_DROPPED]),
        int(hdr[W_LOST]),
        int(hdr[W_FSYNCS]),
        int(hdr[W_BYTES]),
    )


@dataclass(frozen=True)
class RingLayout:
    """Sizes of the shared mapping: ``n_numbers`` float64 per row, ``rows`` row slots,
    ``frames`` CAN records."""

    n_numbers: int
    rows: int
    frames: int

    @property
    def row_floats(self) -> int:
        return self.n_numbers + SLOT_HEAD

    @property
    def events_offset(self) -> int:
        return _ROWS + self.rows * self.row_floats * 8

    @property
    def can_offset(self) -> int:
        return self.events_offset + self.rows * EVENT_BYTES

    @property
    def size(self) -> int:
        return self.can_offset + self.frames * CAN_RECORD.size


class RingMap:
    """The mapping seen through memoryviews (no numpy: the writer process maps it so, see the
    module docstring). ``RingMap(layout, fd)`` maps an existing one; the producer's
    :class:`~cdcr_ctl.runlog.writer.ring.SharedRing` makes it. Not thread-safe on the producer
    side except :meth:`put_frame` under the caller's lock."""

    def __init__(self, layout: RingLayout, fd: int) -> None:
        self.layout = layout
        self.fd = fd
        self.mm = mmap.mmap(fd, layout.size)
        buf = memoryview(self.mm)
        self.buf = buf
        #: The header as a memoryview of int64: a plain item load or store (Python ints).
        self.hq = buf[:_HEADER_BYTES].cast("q")
        #: The row slots as one flat memoryview of float64: a slice store from a float64 array
        #: is a plain memory copy (numpy's indexing costs several times more on the loop's path);
        #: a slot's ``tolist()`` gives its Python floats.
        self.f64 = buf[_ROWS : layout.events_offset].cast("d")
        #: The row slots' bytes (for ``struct.pack_into`` at ``slot * row_floats * 8``).
        self.rows_buf = buf[_ROWS : layout.events_offset]
        self.events = buf[layout.events_offset : layout.can_offset]
        self.can = buf[layout.can_offset : layout.size]

    def close(self) -> None:
        """Close this side's descriptor. The mapping itself goes when the last view of it is
        gone (another thread may still hold one), and with the other process's."""
        with contextlib.suppress(OSError):
            os.close(self.fd)

    # ------------------------------------------------------------------ text areas
    def _put_text(self, offset: int, text: str, size: int = TEXT_BYTES) -> None:
        data = text.encode("utf-8")[: size - 4]
        self.buf[offset + 4 : offset + 4 + len(data)] = data
        struct.pack_into("<I", self.buf, offset, len(data))

    def _get_text(self, offset: int, size: int = TEXT_BYTES) -> str:
        (n,) = struct.unpack_from("<I", self.buf, offset)
        return bytes(self.buf[offset + 4 : offset + 4 + min(n, size - 4)]).decode(
            "utf-8", "replace"
        )

    def set_names(self, names: list[str]) -> None:
        """Producer, before the first slot in :data:`ORDER_NAMES`: the names of its values.
        Raises ValueError if they do not fit the area."""
        text = json.dumps(names)
        if len(text.encode()) > NAMES_BYTES - 4:
            raise ValueError(f"{len(names)} value names do not fit {NAMES_BYTES} bytes")
        self._put_text(_NAMES_TEXT, text, NAMES_BYTES)

    def names(self) -> list[str]:
        """Writer: the names of the values of slots in :data:`ORDER_NAMES`."""
        return json.loads(self._get_text(_NAMES_TEXT, NAMES_BYTES))

    def request_close(self, reason: str, outcome: str, end_utc: str) -> None:
        """Producer: ask the writer to close the run with this end (then no more rows)."""
        doc = {"reason": reason[:1500], "outcome": outcome, "end_utc": end_utc}
        self._put_text(_CLOSE_TEXT, json.dumps(doc))
        self.hq[CLOSE] = 1

    def close_request(self) -> dict[str, str] | None:
        """Writer: the producer's close request, or None."""
        if not self.hq[CLOSE]:
            return None
        return json.loads(self._get_text(_CLOSE_TEXT))

    def set_failure(self, text: str) -> None:
        """Writer: record the write error that stopped the log."""
        self._put_text(_FAIL_TEXT, text)
        self.hq[FAILED] = 1

    def failure(self) -> str | None:
        """Producer: the writer's write error, or None (one int64 load when there is none)."""
        if not self.hq[FAILED]:
            return None
        return self._get_text(_FAIL_TEXT)

    # ------------------------------------------------------------------ row text
    def put_event(self, slot: int, text: str) -> None:
        """Producer: the row's text into ``slot`` (cut to :data:`EVENT_BYTES`, marked)."""
        data = text.encode("utf-8")
        if len(data) > EVENT_BYTES:
            mark = CUT_MARK.encode()
            data = data[: EVENT_BYTES - len(mark)].decode("utf-8", "ignore").encode() + mark
        off = slot * EVENT_BYTES
        self.events[off : off + len(data)] = data
        self.f64[slot * self.layout.row_floats + 1] = float(len(data))

    def get_event(self, slot: int, n: int) -> str:
        off = slot * EVENT_BYTES
        return bytes(self.events[off : off + n]).decode("utf-8", "replace")

    # ------------------------------------------------------------------ CAN frames
    def put_frame(self, ts: float, cob: int, flags: int, dlc: int, data: bytes) -> bool:
        """Producer (one at a time): one CAN frame; False when the ring is full."""
        hq, cap = self.hq, self.layout.frames
        head = hq[CAN_HEAD]
        if cap == 0 or head - hq[CAN_TAIL] >= cap:
            return False
        CAN_RECORD.pack_into(
            self.can, (head % cap) * CAN_RECORD.size, ts, cob, flags, dlc, len(data), data[:64]
        )
        hq[CAN_HEAD] = head + 1
        return True

    def backlog(self) -> float:
        """The fuller of the two rings (rows, CAN frames) as a fraction of its capacity: what
        the producer has published and the writer not yet taken."""
        hq, lay = self.hq, self.layout
        rows = (hq[ROW_HEAD] - hq[ROW_TAIL]) / lay.rows
        frames = (hq[CAN_HEAD] - hq[CAN_TAIL]) / lay.frames if lay.frames else 0.0
        return rows if rows >= frames else frames

    def take_frames(self) -> list[tuple]:
        """Writer: the frames published so far, as the MCAP sink's ``CanTap`` queues them
        (timestamp, id, extended, rx, error, remote, dlc, data)."""
        hq, cap = self.hq, self.layout.frames
        tail, head = hq[CAN_TAIL], hq[CAN_HEAD]
        out = []
        size = CAN_RECORD.size
        for seq in range(tail, head):
            ts, cob, flags, dlc, n, data = CAN_RECORD.unpack_from(self.can, (seq % cap) * size)
            out.append(
                (ts, cob, bool(flags & 1), bool(flags & 2), bool(flags & 4), bool(flags & 8),
                 dlc, data[:n])
            )  # fmt: skip
        hq[CAN_TAIL] = head
        return out
