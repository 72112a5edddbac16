"""The drive group's start-up: NMT boot, identity, the SDO configuration of every drive, NMT
start confirmed by heartbeat, and the reconfiguration of a drive that rebooted.

A mixin of :class:`~cdcr_ctl.drives.group.facade.DriveGroup` (the state lives on the group).
"""

from __future__ import annotations

import struct
import time
from collections.abc import Sequence

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.group.common import (
    BOOT_TIMEOUT_S,
    NMT_COB_ID,
    NMT_RESET_COMMUNICATION,
    NMT_START,
    _Drive,
)
from cdcr_ctl.drives.heartbeat import NMT_OPERATIONAL
from cdcr_ctl.errors import DriveFault, RigTimeoutError


class _Startup:
    """Boot and configuration for :class:`~cdcr_ctl.drives.group.facade.DriveGroup`."""

    def boot(self, timeout_s: float = BOOT_TIMEOUT_S) -> None:
        """NMT reset communication to every drive, then wait for each boot-up message."""
        for d in self._drives:
            d.booted.clear()
        for d in self._drives:
            self._send(NMT_COB_ID, bytes((NMT_RESET_COMMUNICATION, d.id)))
        deadline = self.clock() + timeout_s
        missing = []
        for d in self._drives:
            if d.booted.wait(max(0.0, deadline - self.clock())):
                d.present = True
            else:
                missing.append(d.id)
        if missing:
            raise RigTimeoutError(
                f"node(s) {', '.join(map(str, missing))}: no boot-up message (0x700 + node, [00]) "
                f"within {timeout_s} s of NMT reset communication; check power, wiring, node ids "
                f"and the bit rate ({self.bus_cfg.bitrate} bit/s)"
            )

    def read_identity(self, node_id: int) -> dict[str, int]:
        """0x1000 device type and 0x1018 identity of one drive, by SDO."""
        d = self._by_node[node_id]
        out = {"device_type": self._sdo_read_u32(d, epos.DEVICE_TYPE, 0)}
        for sub, key in ((1, "vendor_id"), (2, "product_code"), (3, "revision"), (4, "serial")):
            out[key] = self._sdo_read_u32(d, epos.IDENTITY, sub)
        return out

    def configure(self) -> None:
        """Check each drive is a maxon drive, SDO-configure it from the config (mode, limits,
        following error, interpolation period, heartbeats, PDO mapping), start the master
        heartbeat, NMT-start every drive and confirm OPERATIONAL from its heartbeat."""
        for d in self._drives:
            self._configure_drive(d)
        self._hb_next_s = self.watch_clock()
        self._hb_on = self._hb_period_s > 0
        now = self.clock()
        for d in self._drives:
            d.last_tpdo_s = now
            d.tpdo_sync = self.sync_count
            d.reset_stream()
            self._heartbeats.commanded(d.id, NMT_OPERATIONAL, self.watch_clock())
            self._send(NMT_COB_ID, bytes((NMT_START, d.id)))
        self._oldest_tpdo_sync = self.sync_count
        self._heartbeats.arm(self.watch_clock())
        self._started = True
        self._confirm_operational()

    def _configure_drive(self, d: _Drive) -> int:
        """Check drive ``d`` is a maxon drive and write its SDO configuration; the writes."""
        vendor = self._sdo_read_u32(d, epos.IDENTITY, 1)
        if vendor != epos.MAXON_VENDOR_ID:
            raise DriveFault(d.id, 0, f"0x1018:1 vendor id 0x{vendor:08X} is not maxon (0xFB)")
        writes = epos.configuration_writes(d.cfg, self.bus_cfg, self.file, self._tables[d.id])
        for w in writes:
            self._sdo_write(d, w)
        if any(w.index == epos.INTERPOLATION_PERIOD for w in writes):
            raw = self._sdo_read(d, epos.INTERPOLATION_PERIOD, 2)
            index = struct.unpack("<b", raw[:1])[0]
            if index != -3:
                raise DriveFault(
                    d.id, 0, f"0x60C2:2 interpolation time index is {index}, expected -3 (ms)"
                )
        d.present = True
        d.rebooted = False
        return len(writes)

    def reconfigure(self, node_id: int) -> str:
        """Configure one drive again (a drive that rebooted lost its SDO configuration: PDO
        mapping, limits, heartbeats): the same writes as :meth:`configure`, then NMT start and
        its OPERATIONAL heartbeat. Not on the loop's path. Returns what was done, as text."""
        self._require_started()
        d = self._by_node[node_id]
        n = self._configure_drive(d)
        now = self.clock()
        d.last_tpdo_s, d.tpdo_sync = now, self.sync_count
        d.reset_stream()
        self._heartbeats.commanded(d.id, NMT_OPERATIONAL, self.watch_clock())
        self._send(NMT_COB_ID, bytes((NMT_START, d.id)))
        self._confirm_operational([d])
        return (
            f"node {d.id}: rebooted (its configuration was lost): reconfigured with {n} SDO "
            "writes and started; its position restarted from 0, home it again"
        )

    @property
    def rebooted_nodes(self) -> list[int]:
        """Drives seen to boot (boot-up message) since :meth:`configure`: not configured."""
        return [d.id for d in self._drives if d.rebooted]

    def _confirm_operational(self, drives: Sequence[_Drive] | None = None) -> None:
        watched = [d for d in drives or self._drives if d.cfg.heartbeat_producer_ms > 0]
        if not watched:
            return
        timeout_s = max(3 * max(d.cfg.heartbeat_producer_ms for d in watched) / 1e3, 0.5)
        deadline = self.clock() + timeout_s
        while True:
            late = [d for d in watched if self._heartbeats.state(d.id) != NMT_OPERATIONAL]
            if not late:
                return
            if self.clock() > deadline:
                raise RigTimeoutError(
                    f"node(s) {', '.join(str(d.id) for d in late)}: no OPERATIONAL heartbeat "
                    f"within {timeout_s:.2f} s of NMT start"
                )
            time.sleep(0.005)
