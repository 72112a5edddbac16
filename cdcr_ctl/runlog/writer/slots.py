"""One run-log row into one slot of the shared ring: the loop's side of the process writer.

:class:`SlotFiller` knows the ring's row layout (:mod:`cdcr_ctl.runlog.writer.ring`): a head of
``SLOT_HEAD`` float64s (the value order's code, the event text's length), then the numeric
columns. A loop row (an object with ``row_parts()``, such as the loop's ``CycleRow``) costs one
packed store of its head and one memoryview copy of its float64 array; its value names are
mapped to columns once (:meth:`SlotFiller.set_names`). Any other row (a mapping or a sequence in
column order) is converted value by value. The writer process turns the slots back into rows.
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Mapping, Sequence
from typing import Any

from cdcr_ctl.runlog.columns import TEXT_COLUMNS, TIME
from cdcr_ctl.runlog.writer.ring import ORDER_COLUMNS, ORDER_NAMES, SLOT_HEAD, SharedRing

log = logging.getLogger("cdcr_ctl.runlog.writer")


class SlotFiller:
    """Fills ring slots with rows of ``columns`` (the run's columns, text ones included).
    ``where``: the file named in warnings. Not thread-safe: one storing thread."""

    def __init__(self, ring: SharedRing, columns: Sequence[str], where: object) -> None:
        self.columns = list(columns)
        self.where = where
        #: Numeric columns (ring order = column order without the text columns) and the text one.
        self.num_cols = [c for c in self.columns if c not in TEXT_COLUMNS]
        self._num_index = {c: j for j, c in enumerate(self.num_cols)}
        text = [c for c in self.columns if c in TEXT_COLUMNS]
        self._text_col = text[0] if text else None
        self._text_pos = self.columns.index(text[0]) if text else -1
        self._parts_keys: Any = None
        self._parts_from = self._parts_to = 0
        self._warned_keys = False
        self._ring = ring
        #: A slot's place in the rows area, in float64s; its bytes for the packed head store.
        self._row_floats = ring.layout.row_floats
        self._f64 = ring.f64
        self._rows_buf = ring.rows_buf
        self._pack_head = struct.Struct("<5d").pack_into  # order, text length, t, cycle, late

    def fill(self, row: Any, slot: int) -> None:
        """Store ``row`` into ``slot`` (see :meth:`ProcessRunLogWriter.write
        <cdcr_ctl.runlog.writer.process.ProcessRunLogWriter.write>` for the row forms). Raises
        (ValueError, TypeError ...) on a row it cannot take; the slot is then not published."""
        parts = getattr(row, "row_parts", None)
        if parts is not None:
            keys, values, t_s, cycle, lateness_s, text = parts()
            if keys is not self._parts_keys:
                self.set_names(keys)
            # One packed store of the head, one copy of the loop's array.
            at = slot * self._row_floats
            self._pack_head(self._rows_buf, at * 8, ORDER_NAMES, 0.0, t_s, cycle, lateness_s)
            try:
                self._f64[at + self._parts_from : at + self._parts_to] = values
            except (TypeError, ValueError):  # not a float64 array: numpy converts
                self._ring.nums[slot, self._parts_from : self._parts_to] = values
        else:
            text = self._fill_plain(row, self._ring.nums[slot])
        if text:
            self._ring.put_event(slot, str(text))

    def set_names(self, keys: Sequence[str]) -> None:
        """The first loop row: its value names into the ring (the writer process maps them to
        columns). One order per writer: a row with other names is refused."""
        if self._parts_keys is not None:
            if tuple(keys) == tuple(self._parts_keys):
                self._parts_keys = keys
                return
            raise ValueError("a row with another layout than the run's first")
        names = [TIME, "cycle", "lateness_us", *keys]
        unknown = [k for k in names if k not in self._num_index]
        if unknown or len(set(names)) != len(names) or len(names) > len(self.num_cols):
            raise ValueError(f"row names not among the columns (or repeated): {unknown}")
        self._ring.set_names(names)
        self._parts_from, self._parts_to = SLOT_HEAD + 3, SLOT_HEAD + len(names)
        self._parts_keys = keys

    def _fill_plain(self, row: Any, nums: Any) -> str:
        if isinstance(row, Mapping):
            if not self._warned_keys and not set(row).issubset(self.columns):
                self._warned_keys = True
                unknown = sorted(set(row) - set(self.columns))
                log.warning("%s: unknown keys ignored: %s", self.where, unknown)
            values = [row.get(c) for c in self.num_cols]
            text = row.get(self._text_col) if self._text_col else None
        else:
            seq = list(row)
            seq = (seq + [None] * len(self.columns))[: len(self.columns)]
            text = seq.pop(self._text_pos) if self._text_pos >= 0 else None
            values = seq
        nums[SLOT_HEAD:] = [math.nan if v is None else float(v) for v in values]
        nums[:SLOT_HEAD] = (ORDER_COLUMNS, 0.0)
        return "" if text is None else str(text)
