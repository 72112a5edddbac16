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
from collections import deque
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


#: Transmitted SYNC and quick-stop frames remembered (enough for the seconds between a stop
#: request and its answer at 1 kHz, where the request may be timed after the frames went out).
HISTORY_FRAMES = 4096


class StopBusTap(can.Listener):
    """Times stop requests against the bus (see the module). Thread-safe: frames arrive on the
    loop thread (sent) and python-can's notifier (received); :meth:`arm` on a socket thread.

    It remembers the last :data:`HISTORY_FRAMES` transmitted SYNC and quick-stop frames, so
    :meth:`arm` may come after the frames it times: the daemon's front process raises the stop
    flag and the rig process arms the tap with the request's arrival time a pipe trip later.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._armed_at: float | None = None
        #: (time, cob_id, is a quick stop) of transmitted SYNC and quick-stop frames.
        self._frames: deque[tuple[float, int, bool]] = deque(maxlen=HISTORY_FRAMES)

    def arm(self, request_wall_s: float) -> None:
        """A stop request arrived at ``request_wall_s`` (``time.time()``): time the first
        quick-stop frame at or after it and count the SYNCs in between."""
        with self._lock:
            self._armed_at = request_wall_s

    def result(self, period_s: float) -> dict[str, Any] | None:
        """What the bus showed since the request :meth:`arm` named: ``quick_stop_after_ms``
        (request arrival to the first quick-stop frame), the same in loop periods (``cycles``),
        ``syncs_before`` (SYNC frames sent in between: bus cycles), ``cob_id``, and both times
        (``time.time()`` s: ``request_wall_s``, ``quick_stop_wall_s``); None before a frame was
        seen."""
        with self._lock:
            armed = self._armed_at
            frames = list(self._frames)
        if armed is None:
            return None
        syncs = 0
        for t, cob, quick_stop in frames:
            if t < armed:
                continue
            if not quick_stop:
                syncs += 1
                continue
            dt = t - armed
            return {
                "request_wall_s": armed,
                "quick_stop_wall_s": t,
                "quick_stop_after_ms": round(dt * 1e3, 3),
                "cycles": round(dt / period_s, 3),
                "syncs_before": syncs,
                "cob_id": f"0x{cob:03X}",
            }
        return None

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_rx:
            return
        cob = msg.arbitration_id
        if cob == SYNC_COB_ID:
            self._frames.append((msg.timestamp, cob, False))  # deque.append: atomic
        elif is_quick_stop_frame(cob, msg.data):
            self._frames.append((msg.timestamp, cob, True))

    def stop(self) -> None:
        """Nothing to close (python-can's listener interface)."""


class TeeListener(can.Listener):
    """Frames to several listeners in order (the run's MCAP channel and the stop tap)."""

    def __init__(self, *listeners: can.Listener) -> None:
        self.listeners = listeners

    def on_message_received(self, msg: can.Message) -> None:
        for listener in self.listeners:
            listener.on_message_received(msg)

    def on_messages(self, msgs: list[can.Message]) -> None:
        """A batch (the traffic log's, see :class:`~cdcr_ctl.drives.group.traffic.
        DeferredTrafficLog`): to each listener as a batch where it takes one."""
        for listener in self.listeners:
            many = getattr(listener, "on_messages", None)
            if many is not None:
                many(msgs)
            else:
                for msg in msgs:
                    listener.on_message_received(msg)

    def stop(self) -> None:
        for listener in self.listeners:
            listener.stop()


__all__ = ["StopBusTap", "TeeListener", "is_quick_stop_frame"]
