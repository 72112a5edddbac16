"""The producer's side of the shared ring (:mod:`cdcr_ctl.runlog.writer.ringmap`, which
describes the layout and the protocol): :class:`SharedRing` makes the mapping, touches its pages,
and adds the numpy views the loop's process stores through (:attr:`SharedRing.nums`, the CAN
records stored a batch at a time by :meth:`SharedRing.put_frames`).
"""

from __future__ import annotations

import os

import numpy as np

from cdcr_ctl.runlog.writer.ringmap import (
    _ROWS,
    CAN_DROPPED,
    CAN_HEAD,
    CAN_RECORD,
    CAN_TAIL,
    CLOSE,
    CUT_MARK,
    DONE,
    EVENT_BYTES,
    FAILED,
    HEADER_SLOTS,
    NAMES_BYTES,
    ORDER_COLUMNS,
    ORDER_NAMES,
    READY,
    ROW_DROPPED,
    ROW_HEAD,
    ROW_TAIL,
    ROW_WAITS,
    ROWS_OFFSET,
    SLOT_HEAD,
    TEXT_BYTES,
    W_BYTES,
    W_DROPPED,
    W_FSYNCS,
    W_HIGH,
    W_LOST,
    W_START,
    W_WRITTEN,
    RingLayout,
    RingMap,
    publish_writer_counts,
    writer_counts,
)

#: Bytes zeroed per store when a new ring's pages are touched (:meth:`SharedRing.create`).
TOUCH_SLICE_BYTES = 64 * 1024
#: The CAN record as a numpy structured type (the same bytes as :data:`CAN_RECORD`), for
#: storing a batch of frames in one assignment.
CAN_DTYPE = np.dtype(
    {
        "names": ["ts", "cob", "flags", "dlc", "n", "data"],
        "formats": ["<f8", "<u4", "u1", "u1", "u1", "S64"],
        "offsets": [0, 8, 12, 13, 14, 15],
        "itemsize": CAN_RECORD.size,
    }
)


class SharedRing(RingMap):
    """The producer's mapping: :class:`~cdcr_ctl.runlog.writer.ringmap.RingMap` plus numpy
    views. ``SharedRing.create(layout)`` makes a new one (its :attr:`fd` goes to the writer
    process), ``SharedRing(layout, fd)`` maps an existing one."""

    def __init__(self, layout: RingLayout, fd: int) -> None:
        super().__init__(layout, fd)
        buf = self.buf
        self.hdr = np.frombuffer(buf, np.int64, HEADER_SLOTS, 0)
        self.nums = np.frombuffer(buf, np.float64, layout.rows * layout.row_floats, _ROWS).reshape(
            layout.rows, layout.row_floats
        )
        self.can_records = np.frombuffer(self.can, CAN_DTYPE, layout.frames)

    @classmethod
    def create(cls, layout: RingLayout) -> SharedRing:
        """A fresh zeroed mapping (Linux ``memfd_create``). Raises OSError."""
        fd = os.memfd_create("cdcr-runlog", 0)  # close-on-exec; passed on explicitly
        try:
            os.ftruncate(fd, layout.size)
            ring = cls(layout, fd)
        except BaseException:
            os.close(fd)
            raise
        # Touch every page of the header, the rows and the CAN records now: a page first
        # written by the loop would cost it a page fault (the shared memory is allocated on
        # first touch), one every few rows during the ring's first round. The ring is sized by
        # time (``logging.ring_s`` of rows at the loop's rate: 10 s at 1 kHz of a 3-cable rig is
        # ~3 MB of rows and 4 MB of CAN records), so this is a bounded cost at the run's start.
        # The text fields (1 kB a slot) are touched only by rows with an event.
        # In slices of TOUCH_SLICE_BYTES (issue #21): one bulk store is one C call that keeps
        # the interpreter lock for all of it (5-11 ms for 7 MB, measured with a real-time probe
        # thread of the same process), and this runs in the loop's process as a run starts;
        # between two slices the loop thread gets the lock back (0.3-0.5 ms at most).
        zeros = bytes(TOUCH_SLICE_BYTES)
        for lo, hi in ((0, layout.events_offset), (layout.can_offset, layout.size)):
            for off in range(lo, hi, TOUCH_SLICE_BYTES):
                n = min(TOUCH_SLICE_BYTES, hi - off)
                ring.buf[off : off + n] = zeros[:n]
        return ring

    def put_frames(self, records: list[tuple]) -> int:
        """Producer (one at a time): CAN frames as ``(timestamp, id, flags, dlc, data length,
        data)`` records (as :meth:`put_frame`'s arguments, ``data`` at most 64 bytes), stored in
        one or two numpy assignments (two where the ring wraps). Returns how many were stored:
        the first ones, as many as the ring has room for."""
        hq, cap = self.hq, self.layout.frames
        head = hq[CAN_HEAD]
        n = min(len(records), cap - (head - hq[CAN_TAIL]))
        if n <= 0:
            return 0
        at = head % cap
        first = min(n, cap - at)
        recs = self.can_records
        recs[at : at + first] = records if first == len(records) else records[:first]
        if n > first:
            recs[: n - first] = records[first:n]
        hq[CAN_HEAD] = head + n
        return n


__all__ = [
    "CAN_DROPPED",
    "CAN_DTYPE",
    "CAN_HEAD",
    "CAN_RECORD",
    "CAN_TAIL",
    "CLOSE",
    "CUT_MARK",
    "DONE",
    "EVENT_BYTES",
    "FAILED",
    "HEADER_SLOTS",
    "NAMES_BYTES",
    "ORDER_COLUMNS",
    "ORDER_NAMES",
    "READY",
    "ROWS_OFFSET",
    "ROW_DROPPED",
    "ROW_HEAD",
    "ROW_TAIL",
    "ROW_WAITS",
    "SLOT_HEAD",
    "TEXT_BYTES",
    "TOUCH_SLICE_BYTES",
    "W_BYTES",
    "W_DROPPED",
    "W_FSYNCS",
    "W_HIGH",
    "W_LOST",
    "W_START",
    "W_WRITTEN",
    "RingLayout",
    "RingMap",
    "SharedRing",
    "publish_writer_counts",
    "writer_counts",
]
