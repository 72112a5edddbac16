"""``stop`` timed on the bus (issue #21): when did the first quick-stop controlword go out after
a stop request arrived, and how many SYNC frames (bus cycles) went out in between.

:class:`StopBusTap` is a python-can listener on the drive group's traffic log (every frame the
group sends, stamped ``time.time()`` right after the adapter took it, and every frame received):
it sees the bus as the CAN log records it, not the loop's own cycle counter. It is installed with
a run's CAN log (:meth:`cdcr_ctl.daemon.commands_log.LogCommands._log_traffic`); without a
traffic log there is nothing to time and ``stop`` says so (``bus: null``).

A quick-stop frame is controlword 0x0002 (CiA 402 "quick stop") either as the 2-byte controlword
RPDO (:func:`cdcr_ctl.drives.epos.controlword_payload`, COB-IDs 0x200-0x57F) or as the expedited
SDO download of 0x6040:00 (:func:`cdcr_ctl.drives.group.common.sdo_controlword_request`,
COB-IDs 0x601-0x67F) the group sends to a drive that is not OPERATIONAL.
"""

from __future__ import annotations

import threading
from typing import Any

import can

from cdcr_ctl.drives.cia402 import CW_QUICK_STOP
from cdcr_ctl.drives.epos import controlword_payload
from cdcr_ctl.drives.group.common import SYNC_COB_ID, sdo_controlword_request

_QS_RPDO = bytes(controlword_payload(CW_QUICK_STOP))
_QS_SDO = bytes(sdo_controlword_request(CW_QUICK_STOP))


def is_quick_stop_frame(cob_id: int, data: bytes) -> bool:
    """Whether a transmitted frame carries controlword 0x0002 (RPDO or SDO 0x6040:00)."""
    if 0x200 <= cob_id <= 0x57F:
        return bytes(data) == _QS_RPDO
    if 0x601 <= cob_id <= 0x67F:
        return bytes(data) == _QS_SDO
    return False


class StopBusTap(can.Listener):
    """Times stop requests against the bus (see the module). Thread-safe: frames arrive on the
    loop thread (sent) and python-can's notifier (received); :meth:`arm` on a socket thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._armed_at: float | None = None
        self._syncs = 0
        self._first: tuple[float, int, int] | None = None  # (time, cob_id, syncs before it)

    def arm(self, request_wall_s: float) -> None:
        """A stop request arrived at ``request_wall_s`` (``time.time()``): time the next
        quick-stop frame and count SYNCs from now."""
        with self._lock:
            self._armed_at, self._syncs, self._first = request_wall_s, 0, None

    def result(self, period_s: float) -> dict[str, Any] | None:
        """What the bus showed since :meth:`arm`: ``quick_stop_after_ms`` (request arrival to
        the first quick-stop frame), the same in loop periods (``cycles``), ``syncs_before``
        (SYNC frames sent in between: bus cycles), ``cob_id``, and both times (``time.time()``
        s: ``request_wall_s``, ``quick_stop_wall_s``); None before a frame was seen."""
        with self._lock:
            if self._armed_at is None or self._first is None:
                return None
            t, cob, syncs = self._first
            dt = t - self._armed_at
            armed = self._armed_at
        return {
            "request_wall_s": armed,
            "quick_stop_wall_s": t,
            "quick_stop_after_ms": round(dt * 1e3, 3),
            "cycles": round(dt / period_s, 3),
            "syncs_before": syncs,
            "cob_id": f"0x{cob:03X}",
        }

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_rx or self._armed_at is None or self._first is not None:
            return
        cob = msg.arbitration_id
        if cob == SYNC_COB_ID:
            with self._lock:
                self._syncs += 1
        elif is_quick_stop_frame(cob, msg.data):
            with self._lock:
                if self._first is None and self._armed_at is not None:
                    self._first = (msg.timestamp, cob, self._syncs)

    def stop(self) -> None:
        """Nothing to close (python-can's listener interface)."""


class TeeListener(can.Listener):
    """Frames to several listeners in order (the run's MCAP channel and the stop tap)."""

    def __init__(self, *listeners: can.Listener) -> None:
        self.listeners = listeners

    def on_message_received(self, msg: can.Message) -> None:
        for listener in self.listeners:
            listener.on_message_received(msg)

    def stop(self) -> None:
        for listener in self.listeners:
            listener.stop()


__all__ = ["StopBusTap", "TeeListener", "is_quick_stop_frame"]
