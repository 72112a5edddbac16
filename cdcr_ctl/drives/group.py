"""All EPOS drives of a rig on one CAN bus: configuration by SDO, cyclic targets by RPDO + SYNC,
feedback by TPDO, EMCY and heartbeat supervision, CiA 402 state changes, homing, quick stop.

Protocol only: a drive is a node id, counts and a mode. The PDO layout (written to every drive by
SDO at start-up, so no EDS is needed):

- RPDO1 (COB-ID 0x200 + id, synchronous): target position 0x607A (int32) -- sent every cycle;
- RPDO2 (COB-ID 0x300 + id, asynchronous): controlword 0x6040 (uint16) -- sent when it changes;
- TPDO1 (COB-ID 0x180 + id, on every SYNC): statusword 0x6041 (uint16), actual position 0x6064
  (int32).

A cycle is :meth:`DriveGroup.send_cycle`: the RPDO1 payloads of every drive are built first
(:func:`rpdo_target_payload`, pure), then sent as one burst followed by SYNC (COB-ID 0x080).
Faults seen by the listeners (EMCY, heartbeat timeout, missing TPDOs, bus errors) are latched;
:meth:`first_fault` names node and code; the loop answers with :meth:`quick_stop`, which sends
controlword 0x0002 to every drive at once.
"""

from __future__ import annotations

import collections
import logging
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import can
import canopen

from cdcr_ctl.config.drives import CanBusConfig, DriveConfig
from cdcr_ctl.drives.cia402 import (
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_FAULT_RESET,
    CW_HOMING_START_BIT,
    CW_NEW_SETPOINT_BIT,
    CW_QUICK_STOP,
    CW_SHUTDOWN,
    MODE_BY_NAME,
    SW_HOMING_ATTAINED,
    SW_HOMING_ERROR,
    SW_TARGET_REACHED,
    Mode,
    State,
    next_controlword,
    state_of,
)
from cdcr_ctl.drives.emcy import decode_emcy, emcy_text
from cdcr_ctl.errors import CommError, DriveFault, RigTimeoutError

log = logging.getLogger(__name__)

SYNC_COB_ID = 0x080
#: Wait for each node's boot-up message after an NMT reset (s).
BOOT_TIMEOUT_S = 5.0
#: SDO request timeout (s).
SDO_TIMEOUT_S = 0.5
#: Each CiA 402 state step must be confirmed by the statusword within this time (s).
STATE_STEP_TIMEOUT_S = 0.5
#: A drive's heartbeat is lost after this many of its producer periods without one.
HEARTBEAT_MISSES = 3
#: Feedback is missing when no TPDO came for this many SYNC periods.
TPDO_MISSES = 3
#: Frames kept for the dump that goes with a fault.
FRAME_RING = 64


def rpdo_target_payload(target_counts: int) -> bytes:
    """RPDO1 data: target position 0x607A, int32 little endian."""
    return struct.pack("<i", target_counts)


def rpdo_controlword_payload(controlword: int) -> bytes:
    """RPDO2 data: controlword 0x6040, uint16 little endian."""
    return struct.pack("<H", controlword & 0xFFFF)


def pvt_payload(position_counts: int, velocity_rpm: int, time_ms: int) -> bytes:
    """EPOS2 interpolation data record (0x20C1): position int32, velocity int24 (rpm), time uint8
    (ms), little endian, 8 bytes."""
    v = max(-(2**23), min(2**23 - 1, int(velocity_rpm)))
    return (
        struct.pack("<i", position_counts)
        + (v & 0xFFFFFF).to_bytes(3, "little")
        + bytes([max(0, min(255, int(time_ms)))])
    )


def parse_pvt_payload(data: bytes) -> tuple[int, int, int]:
    """Inverse of :func:`pvt_payload`."""
    pos = struct.unpack_from("<i", data)[0]
    v = int.from_bytes(data[4:7], "little", signed=True)
    return pos, v, data[7]


def parse_tpdo_feedback(data: bytes) -> tuple[int, int] | None:
    """TPDO1 data -> (statusword, actual position counts); None if the length is wrong."""
    if len(data) != 6:
        return None
    sw, pos = struct.unpack("<Hi", data)
    return sw, pos


def _u8(v: int) -> bytes:
    return struct.pack("<B", v)


def _i8(v: int) -> bytes:
    return struct.pack("<b", v)


def _u16(v: int) -> bytes:
    return struct.pack("<H", v)


def _u32(v: int) -> bytes:
    return struct.pack("<I", v)


def _i32(v: int) -> bytes:
    return struct.pack("<i", v)


def pdo_mapping_writes(
    node_id: int, ip: bool = False, pp: bool = False
) -> list[tuple[int, int, bytes]]:
    """The SDO writes (index, subindex, data) that set up the PDO layout of the module docstring.

    Each PDO is disabled (COB-ID bit 31), remapped, given its transmission type, then enabled
    (CiA 301 7.5.2.35-36 procedure).
    """
    w: list[tuple[int, int, bytes]] = []
    # Interpolated position (EPOS2): RPDO1 carries the 64-bit PVT record 0x20C1:01 instead.
    ip_entry = 0x20C1_0140

    def pdo(comm: int, mapping: int, cob: int, ttype: int, entries: list[int]) -> None:
        w.append((comm, 1, _u32(0x8000_0000 | cob)))
        w.append((mapping, 0, _u8(0)))
        for i, e in enumerate(entries, start=1):
            w.append((mapping, i, _u32(e)))
        w.append((mapping, 0, _u8(len(entries))))
        w.append((comm, 2, _u8(ttype)))
        w.append((comm, 1, _u32(cob)))

    # Profile position takes the target on a controlword edge: its RPDO1 is asynchronous (255)
    # so the target is in place before the edge arrives.
    pdo(0x1400, 0x1600, 0x200 + node_id, 255 if pp else 1, [ip_entry if ip else 0x607A_0020])
    pdo(0x1401, 0x1601, 0x300 + node_id, 255, [0x6040_0010])
    pdo(0x1800, 0x1A00, 0x180 + node_id, 1, [0x6041_0010, 0x6064_0020])
    return w


def configuration_writes(d: DriveConfig, bus: CanBusConfig) -> list[tuple[int, int, bytes]]:
    """Every SDO write that configures drive ``d`` from the rig config (order matters)."""
    mode = MODE_BY_NAME[d.mode]
    period_ms = round(bus.sync_period_s * 1000)
    lo, hi = d.software_limits_counts
    w: list[tuple[int, int, bytes]] = [
        (0x6060, 0, _i8(int(mode))),
        (0x6065, 0, _u32(d.following_error_window_counts)),
        (0x607D, 1, _i32(lo)),
        (0x607D, 2, _i32(hi)),
        (0x6081, 0, _u32(d.max_profile_velocity_rpm)),
        (0x6083, 0, _u32(d.profile_acceleration_rpm_s)),
        (0x6084, 0, _u32(d.profile_acceleration_rpm_s)),
        (0x6085, 0, _u32(d.quick_stop_deceleration_rpm_s)),
        (0x1017, 0, _u16(d.heartbeat_producer_ms)),
        (0x1016, 1, _u32((bus.master_node_id << 16) | d.heartbeat_consumer_ms)),
    ]
    if mode is Mode.CYCLIC_SYNC_POSITION:
        # Interpolation time period = SYNC period: value * 10^index s (index -3: ms).
        w += [(0x60C2, 1, _u8(max(1, period_ms))), (0x60C2, 2, _i8(-3))]
    if mode is Mode.INTERPOLATED_POSITION:
        w += [(0x20C0, 0, struct.pack("<h", -1))]  # EPOS2 IPM sub mode -1: PVT
    return w + pdo_mapping_writes(
        d.node_id, ip=mode is Mode.INTERPOLATED_POSITION, pp=mode is Mode.PROFILE_POSITION
    )


@dataclass(frozen=True)
class Feedback:
    """Latest TPDO of one drive: statusword, position (counts), its CiA 402 state, when (s)."""

    node: int
    statusword: int
    position_counts: int
    state: State
    t_s: float


class _Drive:
    """Per-drive bookkeeping (touched by the notifier thread and the loop thread)."""

    def __init__(self, cfg: DriveConfig, node: canopen.RemoteNode) -> None:
        self.cfg = cfg
        self.node = node
        self.mode = MODE_BY_NAME[cfg.mode]
        self.controlword = CW_DISABLE_VOLTAGE
        self.feedback = Feedback(cfg.node_id, 0, 0, State.UNKNOWN, float("-inf"))
        self.last_heartbeat_s = float("-inf")
        self.nmt_state = -1
        self.new_feedback = threading.Event()
        self.booted = threading.Event()
        self.last_target: int | None = None


class DriveGroup:
    """The drives of one rig, in the order given (the caller's order, e.g. cable order).

    ``bus`` is injected (any python-can bus); the group owns it from here and shuts it down on
    :meth:`close`. Use as a context manager: exit disables the drives and closes the bus even if
    start-up failed half way.
    """

    def __init__(
        self,
        bus: can.BusABC,
        bus_cfg: CanBusConfig,
        drives: Sequence[DriveConfig],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.bus_cfg = bus_cfg
        self.clock = clock
        self.network = canopen.Network(bus)
        self._drives: list[_Drive] = []
        self._by_node: dict[int, _Drive] = {}
        self._fault: tuple[str, str] | None = None
        self._fault_lock = threading.Lock()
        self._frames: collections.deque[tuple[float, str, int, bytes]] = collections.deque(
            maxlen=FRAME_RING
        )
        self._traffic: can.Listener | None = None
        self._traffic_lock = threading.Lock()
        self._heartbeat_task: object = None
        self.sync_count = 0
        #: SYNC counts when the first fault was latched and when quick stop went out (diagnostics).
        self.fault_at_sync: int | None = None
        self.quick_stop_at_sync: int | None = None
        self.feedback_timeout_s = bus_cfg.feedback_timeout_s or TPDO_MISSES * bus_cfg.sync_period_s
        for d in drives:
            node = canopen.RemoteNode(d.node_id, canopen.ObjectDictionary())
            node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT_S
            self.network.add_node(node)
            drive = _Drive(d, node)
            self._drives.append(drive)
            self._by_node[d.node_id] = drive
            self.network.subscribe(0x180 + d.node_id, self._on_tpdo)
            self.network.subscribe(0x080 + d.node_id, self._on_emcy)
            self.network.subscribe(0x700 + d.node_id, self._on_heartbeat)
        self.network.connect()

    # ------------------------------------------------------------------ listeners
    def _on_tpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        drive = self._by_node.get(can_id - 0x180)
        parsed = parse_tpdo_feedback(bytes(data))
        if drive is None or parsed is None:
            return
        sw, pos = parsed
        drive.feedback = Feedback(drive.cfg.node_id, sw, pos, state_of(sw), self.clock())
        drive.new_feedback.set()
        self._record("rx", can_id, data)

    def _on_emcy(self, can_id: int, data: bytearray, timestamp: float) -> None:
        node = can_id - 0x080
        e = decode_emcy(node, bytes(data))
        self._record("rx", can_id, data)
        if e is None or e.code == 0x0000:
            return  # error reset / no error
        log.error("EMCY node %d: 0x%04X %s (register 0x%02X)", node, e.code, e.text, e.register)
        self._latch(f"emcy:node{node}:0x{e.code:04X}", f"node {node}: 0x{e.code:04X} {e.text}")

    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        drive = self._by_node.get(can_id - 0x700)
        if drive is None or not data:
            return
        drive.last_heartbeat_s = self.clock()
        drive.nmt_state = data[0] & 0x7F
        if data[0] == 0x00:
            drive.booted.set()  # boot-up message

    def _latch(self, cause: str, text: str) -> None:
        with self._fault_lock:
            if self._fault is None:
                self._fault = (cause, text)
                self.fault_at_sync = self.sync_count
                log.error("drive fault: %s; last frames:\n%s", text, self.frame_dump())

    def _record(self, direction: str, can_id: int, data: bytes | bytearray) -> None:
        self._frames.append((self.clock(), direction, can_id, bytes(data)))

    def frame_dump(self) -> str:
        """The last frames seen and sent, oldest first, for error reports."""
        return "\n".join(
            f"{t:12.6f} {d} {cid:03X} [{len(b)}] {b.hex(' ')}"
            for t, d, cid, b in list(self._frames)
        )

    # ------------------------------------------------------------------ traffic log
    def log_traffic(self, path: str | Path | None) -> None:
        """Log every frame seen and sent to ``path`` (ASC/BLF by suffix); ``None`` stops."""
        with self._traffic_lock:
            old, self._traffic = self._traffic, None
        if old is not None:
            self.network.notifier.remove_listener(old)
            old.stop()
        if path is not None:
            writer = can.Logger(str(path))
            with self._traffic_lock:
                self._traffic = writer
            self.network.notifier.add_listener(writer)

    def _send(self, cob_id: int, data: bytes) -> None:
        msg = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)
        try:
            self.network.bus.send(msg)
        except (can.CanError, OSError) as exc:
            self._latch("bus:send", f"CAN {self.bus_cfg.interface}:{self.bus_cfg.channel}: {exc}")
            raise CommError(f"CAN send 0x{cob_id:03X} failed: {exc}") from exc
        self._record("tx", cob_id, data)
        traffic = self._traffic
        if traffic is not None:
            msg.timestamp = time.time()
            with self._traffic_lock:
                traffic.on_message_received(msg)

    # ------------------------------------------------------------------ start-up
    def boot(self, timeout_s: float = BOOT_TIMEOUT_S) -> None:
        """NMT reset communication of every drive and wait for each boot-up message.

        The wait is armed before the command goes out (a fast node answers before a wait that
        starts after the send would begin listening).
        """
        for d in self._drives:
            d.booted.clear()
            d.node.nmt.send_command(0x82)
            if not d.booted.wait(timeout_s):
                raise RigTimeoutError(f"node {d.cfg.node_id}: no boot-up within {timeout_s} s")

    def configure(self) -> None:
        """SDO-configure every drive from the config, then NMT start (OPERATIONAL)."""
        for d in self._drives:
            if d.mode is Mode.INTERPOLATED_POSITION and d.cfg.type != "epos2":
                raise DriveFault(d.cfg.node_id, 0, "interpolated position is the EPOS2's mode")
            for index, sub, data in configuration_writes(d.cfg, self.bus_cfg):
                try:
                    d.node.sdo.download(index, sub, data)
                except canopen.SdoAbortedError as exc:
                    raise DriveFault(
                        d.cfg.node_id,
                        exc.code,
                        f"SDO write 0x{index:04X}:{sub} refused: {exc}",
                    ) from exc
                except canopen.SdoCommunicationError as exc:
                    raise CommError(
                        f"node {d.cfg.node_id}: no SDO answer writing 0x{index:04X}:{sub} ({exc})"
                    ) from exc
        self.network.nmt.state = "OPERATIONAL"
        if self.bus_cfg.master_heartbeat_ms > 0:
            self._heartbeat_task = self.network.send_periodic(
                0x700 + self.bus_cfg.master_node_id, [0x05], self.bus_cfg.master_heartbeat_ms / 1e3
            )
        now = self.clock()
        for d in self._drives:
            d.last_heartbeat_s = max(d.last_heartbeat_s, now)

    # ------------------------------------------------------------------ the cycle
    def build_cycle(self, targets_counts: Sequence[int]) -> list[tuple[int, bytes]]:
        """(COB-ID, data) of one cycle: every drive's RPDO1, then SYNC. Pure but for the last
        target kept per IP drive (its PVT velocity is the slope to the new point)."""
        period = self.bus_cfg.sync_period_s
        frames = []
        for d, t in zip(self._drives, targets_counts, strict=True):
            t = int(t)
            if d.mode is Mode.INTERPOLATED_POSITION:
                prev = d.last_target if d.last_target is not None else t
                rpm = (t - prev) / period * 60.0 / d.cfg.encoder_counts_per_rev
                d.last_target = t
                data = pvt_payload(t, round(rpm), round(period * 1000))
            else:
                data = rpdo_target_payload(t)
            frames.append((0x200 + d.cfg.node_id, data))
        frames.append((SYNC_COB_ID, b""))
        return frames

    def send_cycle(self, targets_counts: Sequence[int]) -> None:
        """Send one cycle's targets and the SYNC; check feedback and heartbeat ages."""
        frames = self.build_cycle(targets_counts)
        try:
            for cob, data in frames[:-1]:
                self._send(cob, data)
                d = self._by_node[cob - 0x200]
                if d.mode is Mode.PROFILE_POSITION and d.feedback.state is State.OPERATION_ENABLED:
                    # Profile position: a rising edge of bit 4 takes the new target at once.
                    self._send(0x300 + d.cfg.node_id, rpdo_controlword_payload(0x3F))
                    self._send(0x300 + d.cfg.node_id, rpdo_controlword_payload(d.controlword))
            self._send(SYNC_COB_ID, b"")
        except CommError:
            return
        self.sync_count += 1
        self._check_ages()

    def send_sync(self) -> None:
        """One SYNC alone (homing and other non-cyclic phases still need TPDO feedback)."""
        try:
            self._send(SYNC_COB_ID, b"")
        except CommError:
            return

    def _check_ages(self) -> None:
        now = self.clock()
        period = self.bus_cfg.sync_period_s
        for d in self._drives:
            hb = d.cfg.heartbeat_producer_ms / 1e3
            if hb > 0 and now - d.last_heartbeat_s > HEARTBEAT_MISSES * hb + period:
                self._latch(
                    f"heartbeat:node{d.cfg.node_id}",
                    f"node {d.cfg.node_id}: heartbeat lost ({now - d.last_heartbeat_s:.3f} s)",
                )
            if self.sync_count > TPDO_MISSES and now - d.feedback.t_s > self.feedback_timeout_s:
                self._latch(
                    f"no_feedback:node{d.cfg.node_id}",
                    f"node {d.cfg.node_id}: no TPDO for {now - d.feedback.t_s:.3f} s "
                    "(bus not answering)",
                )

    def feedback(self) -> list[Feedback]:
        """Latest feedback per drive (never blocks)."""
        return [d.feedback for d in self._drives]

    def first_fault(self) -> tuple[str, str] | None:
        return self._fault

    # ------------------------------------------------------------------ state changes
    def set_controlword(self, cw: int, drives: Sequence[_Drive] | None = None) -> None:
        """Send controlword ``cw`` (RPDO2) to the given drives (all by default) at once."""
        for d in drives or self._drives:
            d.controlword = cw
            self._send(0x300 + d.cfg.node_id, rpdo_controlword_payload(cw))

    def quick_stop(self) -> None:
        """Controlword 0x0002 to every drive now; never raises (best effort on a broken bus)."""
        self.quick_stop_at_sync = self.sync_count
        for d in self._drives:
            d.controlword = CW_QUICK_STOP
            try:
                self._send(0x300 + d.cfg.node_id, rpdo_controlword_payload(CW_QUICK_STOP))
            except CommError:
                log.error("quick stop to node %d could not be sent", d.cfg.node_id)

    def _walk(self, target: State, timeout_s: float) -> None:
        """Step every drive through the 402 diagram to ``target`` (needs SYNCs for feedback)."""
        for d in self._drives:
            deadline = self.clock() + timeout_s
            while d.feedback.state is not target:
                cw = next_controlword(d.feedback.state, target)
                if cw is None:
                    if d.feedback.state is State.FAULT:
                        raise DriveFault(d.cfg.node_id, 0, "in FAULT: reset the fault first")
                elif cw != d.controlword or cw == CW_FAULT_RESET:
                    self.set_controlword(cw, [d])
                d.new_feedback.clear()
                if self.clock() > deadline:
                    raise RigTimeoutError(
                        f"node {d.cfg.node_id}: still {d.feedback.state.value} after {timeout_s} s"
                        f" on the way to {target.value} (controlword 0x{d.controlword:04X})"
                    )
                d.new_feedback.wait(min(0.05, timeout_s))

    def enable(self, timeout_s: float = STATE_STEP_TIMEOUT_S * 3) -> None:
        """Drive every drive to OPERATION ENABLED: controlwords 0x06, 0x07, 0x0F as needed.

        The caller keeps SYNC running (the loop does); feedback confirms each step.
        """
        self._walk(State.OPERATION_ENABLED, timeout_s)
        ip = [d for d in self._drives if d.mode is Mode.INTERPOLATED_POSITION]
        if ip:
            # Interpolated position: controlword bit 4 enables the interpolation.
            self.set_controlword(CW_ENABLE_OPERATION | CW_NEW_SETPOINT_BIT, ip)

    def disable(self, timeout_s: float = STATE_STEP_TIMEOUT_S) -> None:
        """Controlword 0x06 (shutdown: READY TO SWITCH ON, power stage off)."""
        try:
            self.set_controlword(CW_SHUTDOWN)
        except CommError:
            log.error("disable could not be sent")

    def reset_faults(self, timeout_s: float = STATE_STEP_TIMEOUT_S) -> None:
        """Fault reset (controlword 0x80 rising edge) on drives in FAULT; clear latched faults."""
        for d in self._drives:
            if d.feedback.state is State.FAULT:
                self.set_controlword(CW_SHUTDOWN & 0x7F, [d])
                self.set_controlword(CW_FAULT_RESET, [d])
        with self._fault_lock:
            self._fault = None
        now = self.clock()
        for d in self._drives:
            d.last_heartbeat_s = max(d.last_heartbeat_s, now)

    def home(self, sync: Callable[[], None], timeout_s: float | None = None) -> list[int]:
        """Home every drive with its 0x6098 method; return the actual positions after homing.

        ``sync`` sends one SYNC (and whatever else a cycle needs) so TPDO feedback keeps coming;
        the caller's loop must not send targets meanwhile. Drives must be OPERATION ENABLED.
        """
        for d in self._drives:
            h = d.cfg.homing
            sdo = d.node.sdo
            sdo.download(0x6060, 0, _i8(Mode.HOMING))
            sdo.download(0x6098, 0, _i8(h.method))
            sdo.download(0x607C, 0, _i32(h.offset_counts))
            sdo.download(0x6099, 1, _u32(h.speed_rpm))
            sdo.download(0x6099, 2, _u32(h.speed_rpm))
            sdo.download(0x609A, 0, _u32(h.acceleration_rpm_s))
            if h.method in (-3, -4):
                sdo.download(0x30B2, 0, _u16(h.current_threshold_mA))
            self.set_controlword(CW_ENABLE_OPERATION, [d])
            self.set_controlword(CW_ENABLE_OPERATION | CW_HOMING_START_BIT, [d])
            deadline = self.clock() + (timeout_s or h.timeout_s)
            while True:
                sync()
                sw = d.feedback.statusword
                if sw & SW_HOMING_ERROR:
                    raise DriveFault(d.cfg.node_id, 0, "homing error (statusword bit 13)")
                if sw & SW_HOMING_ATTAINED and sw & SW_TARGET_REACHED:
                    break
                if self.clock() > deadline:
                    raise RigTimeoutError(f"node {d.cfg.node_id}: homing not attained in time")
                time.sleep(self.bus_cfg.sync_period_s)
            self.set_controlword(CW_ENABLE_OPERATION, [d])
            sdo.download(0x6060, 0, _i8(int(d.mode)))
        for _ in range(3):
            sync()
            time.sleep(self.bus_cfg.sync_period_s)
        return [d.feedback.position_counts for d in self._drives]

    def read_identity(self, node_id: int) -> dict[str, int]:
        """0x1000 device type and 0x1018 identity of one drive, by SDO."""
        node = self._by_node[node_id].node
        out = {"device_type": struct.unpack("<I", node.sdo.upload(0x1000, 0))[0]}
        for sub, key in ((1, "vendor_id"), (2, "product_code"), (3, "revision"), (4, "serial")):
            out[key] = struct.unpack("<I", node.sdo.upload(0x1018, sub))[0]
        return out

    # ------------------------------------------------------------------ shutdown
    def close(self) -> None:
        """Disable the drives, stop the master heartbeat and the traffic log, close the bus."""
        self.disable()
        stop = getattr(self._heartbeat_task, "stop", None)
        if stop is not None:
            stop()
        self.log_traffic(None)
        try:
            self.network.disconnect()
        except (can.CanError, OSError) as exc:
            log.warning("closing the CAN bus: %s", exc)

    def __enter__(self) -> DriveGroup:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = [
    "DriveGroup",
    "Feedback",
    "configuration_writes",
    "emcy_text",
    "parse_tpdo_feedback",
    "pdo_mapping_writes",
    "rpdo_controlword_payload",
    "rpdo_target_payload",
]
