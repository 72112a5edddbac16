"""The drive group's watchdog: EMCY and heartbeat reception, feedback and heartbeat deadlines
checked every SYNC (O(1) while none passed), the master heartbeat thread, and the one fault
latch that quick-stops every drive and keeps the frame dump and the drive's own diagnosis.

A mixin of :class:`~cdcr_ctl.drives.group.facade.DriveGroup` (the state lives on the group).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import threading
import time

from cdcr_ctl.drives.diagnosis import DIAGNOSIS_SDO_TIMEOUT_S, ERROR_CODE, ERROR_HISTORY, Diagnosis
from cdcr_ctl.drives.emcy import decode_emcy
from cdcr_ctl.drives.group.common import (
    IDLE_PERIODS,
    TPDO_MISSES,
    GroupFault,
    _Drive,
)
from cdcr_ctl.drives.heartbeat import NMT_OPERATIONAL
from cdcr_ctl.errors import CommError, RigError

#: One logger for the whole group (the name it had before the group was split up).
log = logging.getLogger("cdcr_ctl.drives.group")


class _Supervision:
    """Supervision for :class:`~cdcr_ctl.drives.group.facade.DriveGroup`."""

    def _on_emcy(self, can_id: int, data: bytearray, timestamp: float) -> None:
        node = can_id - 0x080
        d = self._by_node.get(node)
        if d is None:
            return
        e = decode_emcy(node, bytes(data), d.cfg.type)
        if e is None:
            return
        if e.code == 0x0000:
            log.info("node %d: EMCY error reset", node)
            return
        d.last_emcy = e
        d.fault_text = f"EMCY 0x{e.code:04X} {e.text}"
        log.error("%s (error register 0x%02X)", e, e.register)
        self._latch(f"emcy:node{node}:0x{e.code:04X}", node, e.code, d.fault_text)

    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        d = self._by_node.get(can_id - 0x700)
        if d is None or not data:
            return
        now = self.watch_clock()
        if data[0] == 0:
            d.booted.set()
            # A boot-up still in flight from before an NMT command is not a reboot.
            if self._started and not self._heartbeats.settling(d.id, now):
                d.rebooted = True
        anomaly = self._heartbeats.beat(d.id, data[0], now)
        if anomaly is not None and self._started:
            d.fault_text = anomaly
            self._latch(f"nmt:node{d.id}", d.id, 0, anomaly)

    # ================================================================== faults
    def _latch(
        self, cause: str, node: int, code: int, description: str, due_at_sync: int | None = None
    ) -> None:
        """Record the first fault and quick-stop every drive (from whichever thread saw it)."""
        with self._fault_lock:
            if self._fault is not None or self._closed:
                return
            at = self.sync_count
            fault = GroupFault(
                cause,
                node,
                code,
                description,
                self.clock(),
                at,
                tuple(self._frames),
                at if due_at_sync is None else min(due_at_sync, at),
            )
            self._fault = fault
            self.fault_at_sync = self.sync_count
        if self.react_to_faults and self._started:
            self.quick_stop_all()  # first; the log (formatting 256 frames) can wait
        log.error("drive fault: %s; last frames:\n%s", fault.text, fault.frames)
        if node and self._started and not self._closed:
            # The drive's own records (0x603F, 0x1003), by SDO: off every thread that the
            # loop or the bus listener needs (the answers arrive on the listener's thread).
            threading.Thread(
                target=self._diagnose_fault, args=(fault,), name="drives-diagnosis", daemon=True
            ).start()

    def diagnose(self, node_id: int) -> Diagnosis:
        """Read drive ``node_id``'s error code 0x603F (when its family has it) and its error
        history 0x1003 by SDO (blocking, short timeouts; not on the loop's path)."""
        d = self._by_node[node_id]
        table = self._tables[d.id]
        code: int | None = None
        history: list[int] = []
        timeout = d.node.sdo.RESPONSE_TIMEOUT
        d.node.sdo.RESPONSE_TIMEOUT = DIAGNOSIS_SDO_TIMEOUT_S

        def read(index: int, sub: int) -> int:
            # Once more after a stray answer: the quick stop goes by SDO to a drive that is not
            # OPERATIONAL, and its confirmation may arrive while this read waits.
            try:
                return self._sdo_read_u32(d, index, sub)
            except CommError:
                time.sleep(DIAGNOSIS_SDO_TIMEOUT_S / 10)
                return self._sdo_read_u32(d, index, sub)

        try:
            if table.has(ERROR_CODE, 0):
                code = read(ERROR_CODE, 0)
            n = read(ERROR_HISTORY, 0) & 0xFF
            for sub in range(1, n + 1):
                history.append(read(ERROR_HISTORY, sub))
        except RigError as exc:
            return Diagnosis(d.id, code, tuple(history), d.cfg.type, f"reading stopped: {exc}")
        finally:
            d.node.sdo.RESPONSE_TIMEOUT = timeout
        return Diagnosis(d.id, code, tuple(history), d.cfg.type)

    def _diagnose_fault(self, fault: GroupFault) -> None:
        try:
            text = self.diagnose(fault.node).text
        except Exception as exc:  # a diagnosis must never take the group down
            text = f"diagnosis failed: {exc}"
        with self._fault_lock:
            if self._fault is fault:
                self._fault = dataclasses.replace(fault, diagnosis=text)
        log.error("node %d diagnosis: %s", fault.node, text)

    def first_fault(self) -> tuple[str, str] | None:
        """(cause, text) of the first fault since the last reset, or None. Never blocks."""
        f = self._fault
        return None if f is None else (f.cause, f.text)

    def fault(self) -> GroupFault | None:
        """The first fault since the last reset (with its frame dump), or None."""
        return self._fault

    def raise_if_faulted(self) -> None:
        """Raise the latched fault as DriveFault (a node) or CommError (the bus)."""
        f = self._fault
        if f is not None:
            raise f.error()

    def syncs_before(self, t_s: float) -> int:
        """How many SYNCs had been sent by time ``t_s`` (the group's clock; from the ring of the
        last SYNC send times)."""
        count = self.sync_count
        for n, t in reversed(self._sync_times):
            if t <= t_s:
                return n
            count = n - 1
        return count

    def _supervise(self, now: float) -> None:
        """Every SYNC: feedback deadlines (``now``, the group's clock), then heartbeat deadlines
        (on the watch clock). O(1) while none passed."""
        if not self._started or self._fault is not None:
            return
        if self.sync_count - self._oldest_tpdo_sync > TPDO_MISSES:
            self._oldest_tpdo_sync = min((d.tpdo_sync for d in self._drives), default=0)
            if self.sync_count - self._oldest_tpdo_sync > TPDO_MISSES:
                self._check_feedback(now)
                if self._fault is not None:
                    return
        self._check_heartbeats(now if self.watch_clock is self.clock else self.watch_clock())

    def _feedback_due(self, d: _Drive) -> int:
        """SYNCs sent when drive ``d``'s feedback became overdue: it had left
        :data:`TPDO_MISSES` SYNCs unanswered and the feedback timeout had passed."""
        return max(
            d.tpdo_sync + TPDO_MISSES,
            self.syncs_before(d.last_tpdo_s + self.feedback_timeout_s),
        )

    def _check_feedback(self, now: float) -> None:
        silent = [
            d
            for d in self._drives
            if self.sync_count - d.tpdo_sync > TPDO_MISSES
            and now - d.last_tpdo_s > self.feedback_timeout_s
        ]
        # A drive counts as answering if it answered one of the last two SYNCs (the latest
        # answer may still be on its way). Drives that all fell silent within a few cycles of
        # each other (a bus unplugged between two drives' TPDOs) are the bus, not one drive.
        answering = [d for d in self._drives if self.sync_count - d.tpdo_sync <= 2]
        if silent and not answering and len(self._drives) > 1:
            silent = self._drives
            # Nothing answers: the bus (adapter, cable, termination) rather than one drive.
            oldest = min(d.last_tpdo_s for d in silent)
            for d in silent:
                d.fault_text = "not answering"
            self._latch(
                "no_feedback:all",
                0,
                0,
                f"CAN {self.bus_cfg.interface}:{self.bus_cfg.channel}: no TPDO from any drive "
                f"for {now - oldest:.3f} s: bus not answering",
                due_at_sync=min(self._feedback_due(d) for d in silent),
            )
            return
        for d in silent:
            d.fault_text = "not answering"
            self._latch(
                f"no_feedback:node{d.id}",
                d.id,
                0,
                f"no TPDO for {self.sync_count - d.tpdo_sync} SYNCs "
                f"({now - d.last_tpdo_s:.3f} s): drive not answering",
                due_at_sync=self._feedback_due(d),
            )
            return

    def _check_heartbeats(self, now: float) -> None:
        """Heartbeat deadlines at ``now`` (s, the watch clock)."""
        for node, age in self._heartbeats.overdue(now):
            d = self._by_node[node]
            d.fault_text = "heartbeat lost"
            # The SYNC send times are on the group's clock: a deadline on another clock (the
            # lock-step rig's simulated time) dates the fault at the SYNC that saw it.
            due = (
                self.syncs_before(self._heartbeats.deadline_s(node))
                if self.watch_clock is self.clock
                else None
            )
            self._latch(
                f"heartbeat:node{node}",
                node,
                0,
                f"heartbeat lost (none for {age:.3f} s; producer time "
                f"{d.cfg.heartbeat_producer_ms} ms)",
                due_at_sync=due,
            )
            return

    # ================================================================== watchdog
    def _watch(self) -> None:
        """Master heartbeat producer, and heartbeat checks while no cycle runs."""
        while not self._watchdog_stop.wait(self.watchdog_period_s):
            watch_now = self.watch_clock()
            self.produce_heartbeat(watch_now)
            idle = self.clock() - self._last_cycle_s > IDLE_PERIODS * self.period_s
            if idle and self._started and self._fault is None:
                self._check_heartbeats(watch_now)

    def produce_heartbeat(self, now: float) -> None:
        """Send the master heartbeat if one is due at ``now`` (s, the watch clock). The watchdog
        thread calls this every :attr:`watchdog_period_s`; a caller whose watch clock is
        simulated time calls it as that time advances (the lock-step rig, every period)."""
        if not self._hb_on or now < self._hb_next_s:
            return
        with self._hb_lock:
            if now < self._hb_next_s:
                return  # the other caller sent it
            self._hb_next_s = max(self._hb_next_s + self._hb_period_s, now)
        with contextlib.suppress(CommError):
            self._send(0x700 + self.bus_cfg.master_node_id, bytes((NMT_OPERATIONAL,)))

    def stop_heartbeat(self) -> None:
        """Stop producing the master heartbeat (what a dead master does; tests use it)."""
        self._hb_on = False
