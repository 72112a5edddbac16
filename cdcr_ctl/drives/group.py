"""All EPOS drives of a rig on one CAN bus: boot and SDO configuration, cyclic set-points by RPDO +
SYNC, feedback by TPDO, EMCY and heartbeat supervision, CiA 402 state changes with explicit
timeouts, homing, profile moves, halt, quick stop.

Protocol only: a drive is a node id, counts and a mode (PDO layout in :mod:`cdcr_ctl.drives.epos`).

The loop's path (never blocks on the bus, never waits for an answer):

- :meth:`DriveGroup.build_cycle` -- every frame of one cycle, built first: each drive's set-point
  RPDO, then SYNC (COB-ID 0x080). Pure: it neither sends nor changes the group.
- :meth:`DriveGroup.send_cycle` -- sends them as one burst (one write on an slcan adapter:
  :meth:`~cdcr_ctl.drives.slcan.SlcanBus.send_frames`), then checks each drive's feedback
  deadline and heartbeat deadline, every SYNC, in O(1) while nothing is overdue (the earliest
  deadline is kept; the drives are scanned only once it has passed);
  :meth:`DriveGroup.feedback` -- the latest TPDO of each drive as :class:`Feedback`.
- :meth:`DriveGroup.quick_stop_all` -- controlword 0x0002 to every drive at once; never raises.

Reception: the group's dispatcher is the bus listener's only listener (canopen's
MessageListener is replaced): every frame goes into the frame ring (and the traffic log), the
feedback TPDOs are decoded there with one ``struct`` unpack, everything else goes on to canopen
(SDO, EMCY, heartbeat). An slcan adapter hands the TPDOs over without a ``can.Message``
(:meth:`~cdcr_ctl.drives.slcan.SlcanBus.set_frame_hook`). When no SYNC went out for longer than
the feedback timeout (start-up, a paused loop), a drive's silence counts from the next SYNC.

Faults (an EMCY, a drive reporting FAULT, a heartbeat overdue or a drive restarting, TPDOs missing
for :data:`TPDO_MISSES` SYNCs from one drive or from all of them, a send or receive failure on the
bus) are latched as one :class:`GroupFault` naming node and code, answered at once with
:meth:`DriveGroup.quick_stop_all` from whichever thread saw them (and, should that thread lose the
race, by the next :meth:`~DriveGroup.send_cycle` before its SYNC), so every drive gets its quick
stop within the SYNC period the fault was seen in; then logged with the last :data:`FRAME_RING`
frames. The loop reads :meth:`DriveGroup.first_fault`.

Off the loop's path (blocking, with named timeouts): :meth:`~DriveGroup.boot`,
:meth:`~DriveGroup.configure`, :meth:`~DriveGroup.enable`, :meth:`~DriveGroup.reset_faults`,
:meth:`~DriveGroup.home`, :meth:`~DriveGroup.move_to`. They confirm every step from the TPDO
feedback; when no cycle is running the group sends the SYNCs itself, at the configured period.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import logging
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import can
import canopen
from can.interfaces.slcan import slcanBus
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from cdcr_ctl.config.drives import CanBusConfig, DriveConfig
from cdcr_ctl.drives import epos
from cdcr_ctl.drives.busload import BusLoad, check_drives_bus_load
from cdcr_ctl.drives.canbus import open_bus
from cdcr_ctl.drives.cia402 import (
    CW_CHANGE_IMMEDIATELY_BIT,
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_FAULT_RESET,
    CW_HALT_BIT,
    CW_HOMING_START_BIT,
    CW_IP_ENABLE_BIT,
    CW_NEW_SETPOINT_BIT,
    CW_QUICK_STOP,
    MODE_BY_NAME,
    SW_HOMING_ATTAINED,
    SW_HOMING_ERROR,
    SW_SETPOINT_ACK,
    SW_TARGET_REACHED,
    Mode,
    State,
    next_controlword,
    state_of,
)
from cdcr_ctl.drives.diagnosis import (
    DIAGNOSIS_SDO_TIMEOUT_S,
    ERROR_CODE,
    ERROR_HISTORY,
    Diagnosis,
)
from cdcr_ctl.drives.emcy import Emcy, decode_emcy
from cdcr_ctl.drives.epos import (
    controlword_payload,
    counts_per_s_to_rpm,
    parse_tpdo_feedback,
    pp_setpoint_payload,
    pvt_payload,
    target_payload,
)
from cdcr_ctl.drives.heartbeat import NMT_OPERATIONAL, HeartbeatConsumer
from cdcr_ctl.drives.plan import check_writes, object_table, planned_writes
from cdcr_ctl.drives.slcan import SlcanBus
from cdcr_ctl.errors import CommError, DriveFault, RigError, RigTimeoutError

log = logging.getLogger(__name__)

SYNC_COB_ID = 0x080
NMT_COB_ID = 0x000
NMT_START, NMT_PRE_OPERATIONAL, NMT_RESET_COMMUNICATION = 0x01, 0x80, 0x82
#: Wait for each node's boot-up message after an NMT reset communication (s).
BOOT_TIMEOUT_S = 5.0
#: SDO request timeout (s); one retry follows (canopen's SdoClient).
SDO_TIMEOUT_S = 0.5
#: Each CiA 402 state step must show in the statusword within this time (s).
STATE_STEP_TIMEOUT_S = 0.5
#: A fault reset must show (the drive leaves FAULT) within this time (s).
FAULT_RESET_TIMEOUT_S = 0.5
#: A profile-position move must be acknowledged within this time (s).
SETPOINT_ACK_TIMEOUT_S = 0.5
#: Time allowed for a profile-position move to reach its target (s).
MOVE_TIMEOUT_S = 30.0
#: Feedback is missing when no TPDO came for this many SYNCs (and for feedback_timeout_s).
TPDO_MISSES = 3
#: Consecutive TPDOs reporting FAULT without an EMCY before the group latches the fault itself.
FAULT_TPDOS = 2
#: Frames kept for the dump that goes with a fault.
FRAME_RING = 256
#: A frame that cannot be queued for sending within this time is a bus fault (s). slcan writes
#: block on the serial port instead (python-can reconfigures the port when the timeout changes).
SEND_TIMEOUT_S = 0.005
#: Period of the watchdog thread: master heartbeat, heartbeat checks while no cycle runs (s).
WATCHDOG_PERIOD_S = 0.01
#: No cycle for this many SYNC periods: the group is idle and clocks SYNC itself while waiting.
IDLE_PERIODS = 3
#: Points the EPOS2 PVT buffer gets before interpolation is enabled (controlword bit 4).
IP_PREFILL_POINTS = 3
#: On close: time allowed for quick-stopped drives to stop before power goes off (s).
CLOSE_SETTLE_S = 0.3
#: On close: SDO timeout for the best-effort writes (s).
CLOSE_SDO_TIMEOUT_S = 0.1
#: The SYNC frame (COB-ID, data).
_SYNC_FRAME = (SYNC_COB_ID, b"")


class _Tee(can.Listener):
    """Frames to the traffic file and to a tap; stopping stops both."""

    def __init__(self, first: can.Listener, second: can.Listener) -> None:
        self.first, self.second = first, second

    def on_message_received(self, msg: can.Message) -> None:
        self.first.on_message_received(msg)
        self.second.on_message_received(msg)

    def stop(self) -> None:
        try:
            self.first.stop()
        finally:
            self.second.stop()


@dataclass(frozen=True)
class Feedback:
    """Latest TPDO of one drive: statusword, actual position (counts), its CiA 402 state, when it
    came (s, on the group's clock, ``time.monotonic`` by default) and this drive's fault text
    ('' when none)."""

    node: int
    statusword: int
    position_counts: int
    state: State
    t_s: float
    fault: str = ""


@dataclass(frozen=True)
class GroupFault:
    """The first fault the group latched.

    ``cause`` is machine-readable (``emcy:node2:0x8611``, ``heartbeat:node1``,
    ``no_feedback:node3``, ``no_feedback:all``, ``fault:node2``, ``nmt:node1``,
    ``pdo_length:node1``, ``bus:send``, ``bus:rx``), ``node`` the
    node at fault (0: the bus), ``code`` the EMCY code (0 when none), ``description`` what
    happened, ``at_sync`` the SYNC count when it was seen, ``frames`` the last frames on the bus.
    ``due_at_sync`` is the SYNC count when the fault became a fact: the EMCY's arrival, the
    SYNCs sent before a heartbeat or feedback deadline passed (the group's SYNC count is the
    number of SYNCs sent); the quick stop's delay is ``quick_stop_at_sync - due_at_sync``.
    ``diagnosis`` is what the drive's own records said (0x603F, 0x1003), read after the fault.
    """

    cause: str
    node: int
    code: int
    description: str
    t_s: float
    at_sync: int
    frame_records: tuple[tuple[float, str, int, bytes], ...]
    due_at_sync: int | None = None
    diagnosis: str = ""

    @property
    def frames(self) -> str:
        """The last frames on the bus when the fault was seen: ``t_s dir id [dlc] data``."""
        return format_frames(self.frame_records)

    @property
    def text(self) -> str:
        text = f"node {self.node}: {self.description}" if self.node else self.description
        return f"{text} [{self.diagnosis}]" if self.diagnosis else text

    def error(self) -> RigError:
        """The exception to raise for this fault (DriveFault for a node, CommError for the bus),
        with the frame dump as a note."""
        err: RigError = (
            DriveFault(self.node, self.code, self.description)
            if self.node
            else CommError(self.description)
        )
        if self.diagnosis:
            err.add_note(f"node {self.node}'s own records: {self.diagnosis}")
        err.add_note(f"last CAN frames (t_s dir id [dlc] data):\n{self.frames}")
        return err


def format_frames(frames: Sequence[tuple[float, str, int, bytes]]) -> str:
    """Frame records as text, one per line: ``t_s dir id [dlc] data``."""
    return "\n".join(f"{t:12.6f} {d} {cid:03X} [{len(b)}] {b.hex(' ')}" for t, d, cid, b in frames)


class _Drive:
    """Per-drive bookkeeping (written by the bus listener thread and the caller's thread)."""

    def __init__(self, cfg: DriveConfig, node: canopen.RemoteNode) -> None:
        self.cfg = cfg
        self.id = cfg.node_id
        self.node = node
        self.mode = MODE_BY_NAME[cfg.mode]
        self.layout = epos.pdo_layout(cfg.node_id, self.mode)
        self.controlword = CW_DISABLE_VOLTAGE
        self.feedback = Feedback(cfg.node_id, 0, 0, State.UNKNOWN, float("-inf"))
        self.tpdo_sync = 0
        self.tpdo_count = 0
        self.last_tpdo_s = float("-inf")
        self.fault_tpdos = 0
        self.booted = threading.Event()
        self.present = False
        #: A boot-up message came after configuration: the drive lost its SDO configuration.
        self.rebooted = False
        self.last_emcy: Emcy | None = None
        self.fault_text = ""
        # set-point streams (pp: set/clear of bit 4; ip: PVT points)
        self.last_target: int | None = None
        self.pp_pending = False
        self.ip_points = 0
        self.ip_active = False

    def reset_stream(self) -> None:
        self.last_target, self.pp_pending, self.ip_points, self.ip_active = None, False, 0, False


def sdo_controlword_request(controlword: int) -> bytes:
    """An expedited SDO download of 0x6040:00 (2 bytes): the controlword without PDOs."""
    return bytes((0x2B,)) + struct.pack("<HBH", epos.CONTROLWORD, 0, controlword) + bytes(2)


class _Network(canopen.Network):
    """canopen's Network with every transmission routed through the group (ring, log, lock) and
    every reception through the group's dispatcher ``rx`` (in place of canopen's
    MessageListener): the cyclic TPDOs are decoded there, everything else goes on to canopen's
    :meth:`~canopen.Network.notify` (SDO, EMCY, heartbeat)."""

    #: The bus listener wakes this often when idle; closing waits at most this long (s).
    NOTIFIER_CYCLE = 0.05

    def __init__(
        self,
        bus: can.BusABC,
        transmit: Callable[[int, bytes, bool], None],
        rx: can.Listener,
    ) -> None:
        super().__init__(bus)
        self._transmit = transmit
        self.listeners = [rx]

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self._transmit(can_id, bytes(data), remote)


class _RxTap(can.Listener):
    """Every received frame to the group; a receive error (adapter gone) too. The only listener
    on the bus, called by python-can's notifier thread."""

    def __init__(
        self, on_rx: Callable[[can.Message], None], on_error: Callable[[Exception], None]
    ) -> None:
        self._on_rx = on_rx
        self._on_error = on_error

    def on_message_received(self, msg: can.Message) -> None:
        self._on_rx(msg)

    def on_error(self, exc: Exception) -> None:
        self._on_error(exc)

    def stop(self) -> None:
        pass


class DriveGroup:
    """The drives of one rig, in the order given (the caller's order, e.g. cable order).

    ``bus`` is injected (any python-can bus); the group owns it from here and shuts it down on
    :meth:`close`. Use as a context manager: exit quick-stops and disables the drives, stops the
    master heartbeat and closes the bus, even if start-up failed half way. ``clock`` (default
    ``time.monotonic``) stamps feedback and measures every timeout. ``file`` names the config file
    in errors. The cyclic PDO set must fit ``bus_cfg.max_bus_load`` (ConfigError otherwise).
    """

    def __init__(
        self,
        bus: can.BusABC,
        bus_cfg: CanBusConfig,
        drives: Sequence[DriveConfig],
        clock: Callable[[], float] = time.monotonic,
        *,
        file: str = "",
        react_to_faults: bool = True,
    ) -> None:
        self.bus_cfg = bus_cfg
        self.clock = clock
        self.file = file
        self.react_to_faults = react_to_faults
        try:
            self.bus_load: BusLoad = check_drives_bus_load(
                drives, bus_cfg.sync_period_s, bus_cfg.bitrate, bus_cfg.max_bus_load, file
            )
            # Every SDO write the configuration plans, against the drive's device description
            # or the shipped limits table: a refusal is a ConfigError before the first frame.
            self._tables = {d.node_id: object_table(d, file) for d in drives}
            for d in drives:
                check_writes(
                    d,
                    planned_writes(d, bus_cfg, self._tables[d.node_id], file),
                    self._tables[d.node_id],
                    file,
                )
        except RigError:
            bus.shutdown()
            raise
        self.period_s = bus_cfg.sync_period_s
        self.feedback_timeout_s = bus_cfg.feedback_timeout_s or TPDO_MISSES * self.period_s
        # python-can's own slcan bus reconfigures the port whenever the write timeout changes:
        # its writes block instead. SlcanBus (what open_bus makes) honours a timeout per write.
        stock_slcan = isinstance(bus, slcanBus) and not isinstance(bus, SlcanBus)
        self._send_timeout = None if stock_slcan else SEND_TIMEOUT_S
        #: The bus's one-write burst of (id, data) frames (SlcanBus.send_frames), or None:
        #: frames one by one.
        self._send_frames: Callable[[Sequence[tuple[int, bytes]], float | None], None] | None = (
            getattr(bus, "send_frames", None)
        )
        #: Message objects reused for the cyclic burst (every bus copies or encodes on send).
        self._tx_pool: list[can.Message] = []
        self._frames: collections.deque[tuple[float, str, int, bytes]] = collections.deque(
            maxlen=FRAME_RING
        )
        self._traffic: can.Listener | None = None
        self._traffic_lock = threading.Lock()
        #: Why the traffic log stopped on its own (a write error), or None.
        self.traffic_failure: str | None = None
        self._cycle_lock = threading.RLock()
        #: One SDO transfer at a time (the diagnosis thread and the caller's thread).
        self._sdo_lock = threading.RLock()
        self._fault_lock = threading.Lock()
        self._fb_cond = threading.Condition()
        self._fb_waiters = 0
        self._fault: GroupFault | None = None
        self._closed = False
        self._started = False
        self.sync_count = 0
        self.error_frames = 0
        #: SYNC counts when the first fault was latched and when the quick stop went out.
        self.fault_at_sync: int | None = None
        self.quick_stop_at_sync: int | None = None
        self._last_cycle_s = float("-inf")
        self._last_sync_s = float("-inf")
        #: Send times of the last SYNCs (SYNC count after it, time): deadlines -> SYNC counts.
        self._sync_times: collections.deque[tuple[int, float]] = collections.deque(maxlen=256)
        #: No drive's last TPDO came before this SYNC count (a lower bound; module docstring).
        self._oldest_tpdo_sync = 0
        self._next_self_sync_s = float("-inf")
        self._sync_source: Callable[[], None] | None = None
        self._hb_period_s = bus_cfg.master_heartbeat_ms / 1e3
        self._hb_on = False
        self._hb_next_s = 0.0

        self.network = _Network(bus, self._transmit, _RxTap(self._on_frame, self._on_rx_error))
        self._drives: list[_Drive] = []
        self._by_node: dict[int, _Drive] = {}
        self._by_tpdo: dict[int, _Drive] = {}
        for d in drives:
            node = canopen.RemoteNode(d.node_id, canopen.ObjectDictionary())
            node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT_S
            self.network.add_node(node)
            drive = _Drive(d, node)
            self._drives.append(drive)
            self._by_node[d.node_id] = drive
            self._by_tpdo[drive.layout.feedback.cob_id] = drive  # decoded in _on_frame
            self.network.subscribe(0x080 + d.node_id, self._on_emcy)
            self.network.subscribe(0x700 + d.node_id, self._on_heartbeat)
        self._heartbeats = HeartbeatConsumer(
            {d.node_id: d.heartbeat_producer_ms / 1e3 for d in drives}
        )
        # Receive only what the master consumes: each drive's feedback TPDO, EMCY, heartbeat and
        # SDO responses. On socketcan the kernel filters; elsewhere python-can drops the rest
        # before canopen sees it (a multicast or loopback transport echoes our own frames).
        bus.set_filters(
            [
                {"can_id": cob, "can_mask": 0x7FF, "extended": False}
                for d in self._drives
                for cob in (
                    d.layout.feedback.cob_id,
                    0x080 + d.cfg.node_id,
                    0x700 + d.cfg.node_id,
                    0x580 + d.cfg.node_id,
                )
            ]
        )
        # A bus that can hand the cyclic TPDOs over without a Message (SlcanBus) does so.
        set_frame_hook = getattr(bus, "set_frame_hook", None)
        if callable(set_frame_hook):
            set_frame_hook(list(self._by_tpdo), self._on_tpdo_frame)
        self.network.connect()
        self._watchdog_stop = threading.Event()
        self._watchdog = threading.Thread(target=self._watch, name="drives-watchdog", daemon=True)
        self._watchdog.start()

    # ================================================================== transmit / receive
    def _transmit(self, can_id: int, data: bytes, remote: bool = False) -> None:
        """Send one frame (every frame the group and canopen send comes here)."""
        msg = can.Message(
            arbitration_id=can_id,
            data=data,
            is_extended_id=can_id > 0x7FF,
            is_remote_frame=remote,
            is_rx=False,
        )
        with self.network.send_lock:
            self.network.bus.send(msg, self._send_timeout)
            self._frames.append((self.clock(), "tx", can_id, data))
        if self._traffic is not None:
            msg.timestamp = time.time()
            self._log_frame(msg)

    def _send(self, cob_id: int, data: bytes) -> None:
        """Send one frame; a failure latches a bus fault and raises CommError."""
        try:
            self._transmit(cob_id, data)
        except (can.CanError, OSError, RuntimeError) as exc:
            self._send_failed(cob_id, exc)

    def _send_failed(self, cob_id: int, exc: Exception) -> NoReturn:
        where = f"CAN {self.bus_cfg.interface}:{self.bus_cfg.channel}"
        self._latch("bus:send", 0, 0, f"{where}: sending 0x{cob_id:03X} failed ({exc})")
        raise CommError(f"{where}: sending 0x{cob_id:03X} failed ({exc})") from exc

    def _send_burst(self, frames: Sequence[tuple[int, bytes]]) -> None:
        """Send the frames of one cycle (standard ids) back to back, in order: one write where
        the bus has a burst (:meth:`SlcanBus.send_frames`), else frame by frame with reused
        Message objects. A failure latches a bus fault and raises CommError."""
        cob = frames[0][0]
        try:
            with self.network.send_lock:
                if self._send_frames is not None:
                    self._send_frames(frames, self._send_timeout)
                else:
                    pool = self._tx_pool
                    while len(pool) < len(frames):
                        pool.append(can.Message(is_extended_id=False, is_rx=False))
                    bus, timeout = self.network.bus, self._send_timeout
                    for m, (cob, data) in zip(pool, frames, strict=False):
                        m.arbitration_id = cob
                        m.data = bytearray(data)
                        m.dlc = len(data)
                        bus.send(m, timeout)
                t = self.clock()
                ring = self._frames
                for cob, data in frames:
                    ring.append((t, "tx", cob, data))
        except (can.CanError, OSError, RuntimeError) as exc:
            self._send_failed(cob, exc)
        if self._traffic is not None:
            stamp = time.time()
            for cob, data in frames:
                self._log_frame(
                    can.Message(
                        timestamp=stamp,
                        arbitration_id=cob,
                        data=data,
                        is_extended_id=cob > 0x7FF,
                        is_rx=False,
                    )
                )

    def _on_frame(self, msg: can.Message) -> None:
        """Every received frame (python-can's notifier thread): into the ring and the traffic
        log, then the cyclic TPDOs decoded here and everything else to canopen's dispatch."""
        now = self.clock()
        cob = msg.arbitration_id
        data = msg.data
        self._frames.append((now, "rx", cob, bytes(data)))
        if self._traffic is not None:
            self._log_frame(msg)
        if msg.is_error_frame:
            self.error_frames += 1
            return
        if msg.is_remote_frame:
            return
        try:
            d = self._by_tpdo.get(cob)
            if d is not None:
                self._on_tpdo(d, data, now)
            else:
                self.network.notify(cob, data, msg.timestamp)
        except Exception:  # as canopen's listener: a handler's bug must not stop reception
            log.exception("handling CAN frame 0x%03X failed", cob)

    def _log_frame(self, msg: can.Message) -> None:
        """One frame to the traffic log. A write error (disk full) stops the traffic log and is
        kept in :attr:`traffic_failure`; it is not a bus fault and never reaches the caller."""
        traffic = self._traffic
        if traffic is None:
            return
        try:
            with self._traffic_lock:
                traffic.on_message_received(msg)
        except (OSError, ValueError) as exc:
            with self._traffic_lock:
                if self._traffic is traffic:
                    self._traffic = None
                    self.traffic_failure = f"CAN traffic log: {exc}"
                    with contextlib.suppress(Exception):
                        traffic.stop()
            log.error("CAN traffic log stopped: %s", exc)

    def _on_rx_error(self, exc: Exception) -> None:
        """The bus listener failed to receive (adapter unplugged, interface down): latch a bus
        fault at once; the listener keeps trying, no faster than its cycle, until close."""
        where = f"CAN {self.bus_cfg.interface}:{self.bus_cfg.channel}"
        self._latch("bus:rx", 0, 0, f"{where}: receiving failed ({exc})")
        if not self._closed:
            time.sleep(_Network.NOTIFIER_CYCLE)

    def _on_tpdo_frame(self, can_id: int, data: bytes, timestamp: float) -> None:
        """A feedback TPDO straight from the bus's receive path (:meth:`SlcanBus.set_frame_hook`,
        python-can's notifier thread): what :meth:`_on_frame` does with it, without a Message."""
        now = self.clock()
        self._frames.append((now, "rx", can_id, data))
        try:
            if self._traffic is not None:
                msg = can.Message(
                    timestamp=timestamp, arbitration_id=can_id, data=data, is_extended_id=False
                )
                self._log_frame(msg)
            self._on_tpdo(self._by_tpdo[can_id], data, now)
        except Exception:  # the bus's receive path must go on
            log.exception("handling CAN frame 0x%03X failed", can_id)

    def _on_tpdo(self, d: _Drive, data: bytes | bytearray, now: float) -> None:
        """Drive ``d``'s feedback TPDO (statusword, position), received at ``now``."""
        parsed = parse_tpdo_feedback(data)
        if parsed is None:
            self._latch(
                f"pdo_length:node{d.id}",
                d.id,
                0,
                f"TPDO1 0x{d.layout.feedback.cob_id:03X} has {len(data)} bytes, expected 6 "
                "(mapping changed?)",
            )
            return
        sw, pos = parsed
        state = state_of(sw)
        d.feedback = Feedback(d.id, sw, pos, state, now, d.fault_text)
        d.tpdo_sync = self.sync_count
        d.tpdo_count += 1
        d.last_tpdo_s = now
        if state is State.FAULT and self._started:
            d.fault_tpdos += 1
            if d.fault_tpdos >= FAULT_TPDOS and d.last_emcy is None:
                self._latch(
                    f"fault:node{d.id}",
                    d.id,
                    0,
                    f"statusword 0x{sw:04X} reports FAULT (no EMCY seen)",
                    due_at_sync=self.sync_count - (FAULT_TPDOS - 1),
                )
        else:
            d.fault_tpdos = 0
        if self._fb_waiters:
            with self._fb_cond:
                self._fb_cond.notify_all()

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
        if data[0] == 0:
            d.booted.set()
            if self._started:
                d.rebooted = True
        anomaly = self._heartbeats.beat(d.id, data[0], self.clock())
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

    def frame_dump(self) -> str:
        """The last frames seen and sent, oldest first: ``t_s dir id [dlc] data``."""
        return format_frames(tuple(self._frames))

    # ================================================================== traffic log
    def log_traffic(self, path: str | Path | None, tap: can.Listener | None = None) -> None:
        """Log every frame seen and sent to ``path`` (python-can writer chosen by suffix: .asc,
        .blf, .csv, .log, ...) and to ``tap`` if given (e.g. the run's MCAP ``/can`` channel);
        ``None`` stops and closes the file."""
        with self._traffic_lock:
            old, self._traffic = self._traffic, None
            if old is not None:
                try:
                    old.stop()
                except (OSError, ValueError) as exc:  # disk full: the next log may still work
                    log.error("CAN traffic log: closing failed: %s", exc)
            if path is not None:
                Path(path).parent.mkdir(parents=True, exist_ok=True)
                logger = can.Logger(str(path))
                self._traffic = logger if tap is None else _Tee(logger, tap)
                self.traffic_failure = None

    # ================================================================== start-up
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
        self._hb_next_s = self.clock()
        self._hb_on = self._hb_period_s > 0
        now = self.clock()
        for d in self._drives:
            d.last_tpdo_s = now
            d.tpdo_sync = self.sync_count
            d.reset_stream()
            self._send(NMT_COB_ID, bytes((NMT_START, d.id)))
        self._oldest_tpdo_sync = self.sync_count
        self._heartbeats.arm(now)
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

    def _sdo_read(self, d: _Drive, index: int, sub: int) -> bytes:
        try:
            with self._sdo_lock:
                return d.node.sdo.upload(index, sub)
        except SdoAbortedError as exc:
            raise DriveFault(
                d.id, exc.code, f"SDO read 0x{index:04X}:{sub:02X} refused: {exc}"
            ) from exc
        except SdoCommunicationError as exc:
            raise CommError(
                f"node {d.id}: no SDO answer reading 0x{index:04X}:{sub:02X} ({exc})"
            ) from exc

    def _sdo_read_u32(self, d: _Drive, index: int, sub: int) -> int:
        raw = self._sdo_read(d, index, sub)
        return int.from_bytes(raw[:4].ljust(4, b"\0"), "little")

    def _sdo_write(self, d: _Drive, w: epos.SdoWrite) -> None:
        try:
            with self._sdo_lock:
                d.node.sdo.download(w.index, w.sub, w.data)
        except SdoAbortedError as exc:
            raise DriveFault(
                d.id, exc.code, f"SDO write 0x{w.index:04X}:{w.sub:02X} ({w.what}) refused: {exc}"
            ) from exc
        except SdoCommunicationError as exc:
            raise CommError(
                f"node {d.id}: no SDO answer writing 0x{w.index:04X}:{w.sub:02X} ({w.what}): {exc}"
            ) from exc

    # ================================================================== the cycle
    def _plan(self, targets_counts: Sequence[int]) -> tuple[list[tuple[int, bytes]], list[tuple]]:
        """Frames of one cycle (without SYNC) and each drive's stream state after it. Pure."""
        frames: list[tuple[int, bytes]] = []
        states: list[tuple] = []
        faulted = self._fault is not None
        period_ms = round(self.period_s * 1e3)
        for d, t in zip(self._drives, targets_counts, strict=True):
            t = int(t)
            last, pending, points, active = d.last_target, d.pp_pending, d.ip_points, d.ip_active
            cob = d.layout.setpoint.cob_id
            if d.mode in (Mode.CYCLIC_SYNC_POSITION, Mode.POSITION_MODE):
                # A synchronous target: one RPDO, no stream state but the last target.
                frames.append((cob, target_payload(t)))
                states.append((t, pending, points, active))
                continue
            enabled = (
                not faulted
                and d.feedback.state is State.OPERATION_ENABLED
                and d.controlword & 0x8F == CW_ENABLE_OPERATION
            )
            if d.mode is Mode.PROFILE_POSITION:
                cw = d.controlword & ~(CW_NEW_SETPOINT_BIT | CW_CHANGE_IMMEDIATELY_BIT)
                if not enabled:
                    last, pending = None, False
                elif pending:
                    frames.append((cob, pp_setpoint_payload(last or 0, cw)))
                    pending = False
                elif t != last:
                    bits = CW_NEW_SETPOINT_BIT | CW_CHANGE_IMMEDIATELY_BIT
                    frames.append((cob, pp_setpoint_payload(t, cw | bits)))
                    last, pending = t, True
            elif d.mode is Mode.INTERPOLATED_POSITION:
                if not enabled:
                    last, points, active = None, 0, False
                else:
                    v = 0 if last is None else (t - last) / self.period_s
                    rpm = counts_per_s_to_rpm(v, d.cfg.encoder_counts_per_rev)
                    frames.append((cob, pvt_payload(t, rpm, period_ms)))
                    last, points = t, points + 1
                    if not active and points >= IP_PREFILL_POINTS:
                        cw = d.controlword | CW_IP_ENABLE_BIT
                        frames.append((d.layout.controlword.cob_id, controlword_payload(cw)))
                        active = True
            states.append((last, pending, points, active))
        return frames, states

    def build_cycle(self, targets_counts: Sequence[int]) -> list[tuple[int, bytes]]:
        """(COB-ID, data) of every frame of one cycle: the set-point RPDOs, then SYNC. Pure: it
        neither sends nor changes the group. ``targets_counts`` in the group's drive order."""
        frames, _ = self._plan(targets_counts)
        return [*frames, _SYNC_FRAME]

    def send_cycle(self, targets_counts: Sequence[int]) -> None:
        """Send one cycle's set-points as one burst, then SYNC; then check feedback and heartbeat
        ages. Never blocks on an answer; a send failure is latched as a fault, not raised."""
        if self._closed:
            return
        now = self.clock()
        with self._cycle_lock:
            self._send_pending_quick_stop()
            frames, states = self._plan(targets_counts)
            frames.append(_SYNC_FRAME)
            self._sync_starts(now)
            try:
                self._send_burst(frames)
            except CommError:
                return
            for d, (last, pending, points, active) in zip(self._drives, states, strict=True):
                d.last_target, d.pp_pending, d.ip_points = last, pending, points
                if active and not d.ip_active:
                    d.controlword |= CW_IP_ENABLE_BIT
                d.ip_active = active
            self.sync_count += 1
            self._sync_times.append((self.sync_count, now))
            self._last_cycle_s = now
        self._supervise(now)

    def send_sync(self) -> None:
        """One SYNC alone (non-cyclic phases still need TPDO feedback); then the same checks."""
        if self._closed:
            return
        now = self.clock()
        with self._cycle_lock:
            self._send_pending_quick_stop()
            self._sync_starts(now)
            try:
                self._send(SYNC_COB_ID, b"")
            except CommError:
                return
            self.sync_count += 1
            self._sync_times.append((self.sync_count, now))
        self._supervise(self.clock())

    def _sync_starts(self, now: float) -> None:
        """Before each SYNC (cycle lock held): when no SYNC went out for longer than the feedback
        timeout (start-up, homing by the caller, a paused loop), no TPDO was due meanwhile, so
        each drive's silence counts from this SYNC. Otherwise a cycle that starts later than
        that after :meth:`configure` would find every drive "not answering" before its first
        TPDO had time to come back (over slcan to another process: a few ms)."""
        if now - self._last_sync_s > self.feedback_timeout_s:
            for d in self._drives:
                d.tpdo_sync = self.sync_count
                d.last_tpdo_s = max(d.last_tpdo_s, now)
            self._oldest_tpdo_sync = self.sync_count
        self._last_sync_s = now

    def _send_pending_quick_stop(self) -> None:
        """A fault seen by another thread whose quick stop has not gone out yet (that thread
        waits for the cycle lock): send it now, before this SYNC (cycle lock held)."""
        pending = self._fault is not None and self.quick_stop_at_sync is None
        if pending and self._started and self.react_to_faults:
            self.quick_stop_all()

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
        """Every SYNC: feedback deadlines, then heartbeat deadlines. O(1) while none passed."""
        if not self._started or self._fault is not None:
            return
        if self.sync_count - self._oldest_tpdo_sync > TPDO_MISSES:
            self._oldest_tpdo_sync = min((d.tpdo_sync for d in self._drives), default=0)
            if self.sync_count - self._oldest_tpdo_sync > TPDO_MISSES:
                self._check_feedback(now)
                if self._fault is not None:
                    return
        self._check_heartbeats(now)

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
        for node, age in self._heartbeats.overdue(now):
            d = self._by_node[node]
            d.fault_text = "heartbeat lost"
            self._latch(
                f"heartbeat:node{node}",
                node,
                0,
                f"heartbeat lost (none for {age:.3f} s; producer time "
                f"{d.cfg.heartbeat_producer_ms} ms)",
                due_at_sync=self.syncs_before(self._heartbeats.deadline_s(node)),
            )
            return

    def feedback(self) -> list[Feedback]:
        """Latest feedback per drive, in the group's order (never blocks)."""
        return [d.feedback for d in self._drives]

    @property
    def node_ids(self) -> list[int]:
        return [d.id for d in self._drives]

    def tpdo_counts(self) -> list[int]:
        """TPDOs received per drive since the group was made (statistics)."""
        return [d.tpdo_count for d in self._drives]

    # ================================================================== watchdog
    def _watch(self) -> None:
        """Master heartbeat producer, and heartbeat checks while no cycle runs."""
        while not self._watchdog_stop.wait(WATCHDOG_PERIOD_S):
            now = self.clock()
            if self._hb_on and now >= self._hb_next_s:
                self._hb_next_s = max(self._hb_next_s + self._hb_period_s, now)
                with contextlib.suppress(CommError):
                    self._send(0x700 + self.bus_cfg.master_node_id, bytes((NMT_OPERATIONAL,)))
            idle = now - self._last_cycle_s > IDLE_PERIODS * self.period_s
            if idle and self._started and self._fault is None:
                self._check_heartbeats(now)

    def stop_heartbeat(self) -> None:
        """Stop producing the master heartbeat (what a dead master does; tests use it)."""
        self._hb_on = False

    # ================================================================== state changes
    def _send_controlword(self, d: _Drive, cw: int) -> None:
        with self._cycle_lock:
            d.controlword = cw
            self._send(d.layout.controlword.cob_id, controlword_payload(cw))

    def quick_stop_all(self) -> None:
        """Controlword 0x0002 (quick stop) to every drive now, by RPDO; a drive whose heartbeat
        says it is not OPERATIONAL (PDOs do not reach it) gets it by an SDO write too (sent
        without waiting for the answer). Never raises (best effort on a broken bus)."""
        if self._closed:
            return
        with self._cycle_lock:
            if self.quick_stop_at_sync is None:
                self.quick_stop_at_sync = self.sync_count
            for d in self._drives:
                d.reset_stream()
                try:
                    self._send_controlword(d, CW_QUICK_STOP)
                    nmt = self._heartbeats.state(d.id)
                    if nmt is not None and nmt != NMT_OPERATIONAL:
                        self._send(0x600 + d.id, sdo_controlword_request(CW_QUICK_STOP))
                except (CommError, RigError):
                    log.error("quick stop to node %d could not be sent", d.id)

    quick_stop = quick_stop_all

    def disable_all(self) -> None:
        """Controlword 0x0000 (disable voltage: power stage off, SWITCH ON DISABLED) to every
        drive; valid from every state but FAULT. Never raises."""
        if self._closed:
            return
        with self._cycle_lock:
            for d in self._drives:
                d.reset_stream()
                try:
                    self._send_controlword(d, CW_DISABLE_VOLTAGE)
                except (CommError, RigError):
                    log.error("disable to node %d could not be sent", d.id)

    disable = disable_all

    def halt_all(self) -> None:
        """Set the halt bit (8): every drive decelerates on its profile deceleration and holds."""
        with self._cycle_lock:
            for d in self._drives:
                self._send_controlword(d, d.controlword | CW_HALT_BIT)

    def resume_all(self) -> None:
        """Clear the halt bit."""
        with self._cycle_lock:
            for d in self._drives:
                self._send_controlword(d, d.controlword & ~CW_HALT_BIT)

    def _require_started(self) -> None:
        if not self._started:
            raise RigError("drives are not configured: call boot() and configure() first")
        if self._closed:
            raise RigError("the drive group is closed")

    def _require_no_fault(self) -> None:
        f = self._fault
        if f is not None:
            err = f.error()
            err.add_note("reset_faults() first")
            raise err

    def _await_feedback(self, max_wait_s: float) -> None:
        """Wait for the next TPDO (at most ``max_wait_s``); clock SYNC if no cycle runs."""
        now = self.clock()
        if (
            now - self._last_cycle_s > IDLE_PERIODS * self.period_s
            and now >= self._next_self_sync_s
        ):
            self._next_self_sync_s = now + self.period_s
            if self._sync_source is not None:
                self._sync_source()
            else:
                self.send_sync()
        with self._fb_cond:
            self._fb_waiters += 1
            try:
                self._fb_cond.wait(min(max_wait_s, self.period_s))
            finally:
                self._fb_waiters -= 1

    def _wait_for(
        self,
        drives: Sequence[_Drive],
        done: Callable[[_Drive], bool],
        timeout_s: float,
        what: str,
        after_sync: int | None = None,
    ) -> None:
        """Wait until ``done(d)`` for every drive, on feedback newer than SYNC ``after_sync``."""
        deadline = self.clock() + timeout_s
        while True:
            self._require_no_fault()
            late = [
                d
                for d in drives
                if not (after_sync is None or d.tpdo_sync > after_sync) or not done(d)
            ]
            if not late:
                return
            if self.clock() > deadline:
                d = late[0]
                raise RigTimeoutError(
                    f"node {d.id}: {what} not confirmed within {timeout_s} s (state "
                    f"{d.feedback.state.value}, statusword 0x{d.feedback.statusword:04X})"
                )
            self._await_feedback(deadline - self.clock())

    def _walk(self, target: State, step_timeout_s: float) -> None:
        """Step every drive through the 402 diagram to ``target``, all drives at once; each
        step must show in the statusword within ``step_timeout_s``."""
        self._require_started()
        sent: dict[int, tuple[State, int]] = {}
        last_states = [d.feedback.state for d in self._drives]
        deadline = self.clock() + step_timeout_s
        while True:
            self._require_no_fault()
            states = [d.feedback.state for d in self._drives]
            if all(s is target for s in states):
                return
            if states != last_states:
                deadline = self.clock() + step_timeout_s
                last_states = states
            with self._cycle_lock:
                self._require_no_fault()
                for d, s in zip(self._drives, states, strict=True):
                    if s is State.FAULT:
                        code = d.last_emcy.code if d.last_emcy else 0
                        raise DriveFault(
                            d.id,
                            code,
                            f"in FAULT ({d.fault_text or 'no EMCY'}): reset_faults() first",
                        )
                    cw = next_controlword(s, target)
                    if cw is not None and sent.get(d.id) != (s, cw):
                        self._send_controlword(d, cw)
                        sent[d.id] = (s, cw)
            if self.clock() > deadline:
                late = [d for d in self._drives if d.feedback.state is not target]
                d = late[0]
                raise RigTimeoutError(
                    f"node {d.id}: still {d.feedback.state.value} {step_timeout_s} s after "
                    f"controlword 0x{d.controlword:04X} on the way to {target.value}"
                )
            self._await_feedback(max(0.0, deadline - self.clock()))

    def enable(self, timeout_s: float = STATE_STEP_TIMEOUT_S) -> None:
        """Every drive to OPERATION ENABLED: controlwords 0x06, 0x07, 0x0F as each needs, all
        drives at once, each step confirmed by the statusword within ``timeout_s``."""
        self._walk(State.OPERATION_ENABLED, timeout_s)
        for d in self._drives:
            d.reset_stream()

    def reset_faults(self, timeout_s: float = FAULT_RESET_TIMEOUT_S) -> list[str]:
        """Fault reset (controlword 0x80 rising edge) of every drive in FAULT, confirmed by its
        statusword leaving FAULT within ``timeout_s``; then check every drive answers (TPDO and
        heartbeat) and clear the latched fault. A drive that rebooted since configuration is
        reconfigured first (:meth:`reconfigure`). Returns what was done beyond the reset, one
        line per drive (the reconfigured ones). Raises DriveFault naming the node when a reset
        does not take, a reconfiguration fails or a drive does not answer."""
        self._require_started()
        notes = []
        for node in self.rebooted_nodes:
            try:
                notes.append(self.reconfigure(node))
            except RigError as exc:
                raise DriveFault(
                    node, 0, f"rebooted and lost its configuration; reconfiguring failed: {exc}"
                ) from exc
        faulted = [
            d
            for d in self._drives
            # FAULT in its feedback, or an EMCY whose FAULT statusword is still on its way (the
            # drive samples its statusword at the SYNC: the feedback lags a cycle)
            if d.feedback.state in (State.FAULT, State.FAULT_REACTION_ACTIVE)
            or d.last_emcy is not None
        ]
        with self._cycle_lock:
            for d in faulted:
                self._send_controlword(d, CW_DISABLE_VOLTAGE)
                self._send_controlword(d, CW_FAULT_RESET)
            start = self.sync_count
        deadline = self.clock() + timeout_s

        def still_faulted(d: _Drive) -> bool:
            # confirmed only by feedback sampled at a SYNC sent after the reset
            faulty = d.feedback.state in (State.FAULT, State.FAULT_REACTION_ACTIVE)
            return faulty or d.tpdo_sync <= start

        while any(still_faulted(d) for d in faulted):
            if self.clock() > deadline:
                d = next(d for d in faulted if still_faulted(d))
                code = d.last_emcy.code if d.last_emcy else 0
                raise DriveFault(
                    d.id,
                    code,
                    f"fault reset not confirmed: still FAULT {timeout_s} s after controlword "
                    f"0x0080 ({d.fault_text or 'no EMCY'})",
                )
            self._await_feedback(max(0.0, deadline - self.clock()))
        with self._cycle_lock:
            for d in faulted:
                self._send_controlword(d, CW_DISABLE_VOLTAGE)
        now = self.clock()
        for d in self._drives:
            if (
                self.sync_count - d.tpdo_sync > TPDO_MISSES
                and now - d.last_tpdo_s > self.feedback_timeout_s
            ):
                raise DriveFault(
                    d.id,
                    0,
                    f"not answering (no TPDO for {now - d.last_tpdo_s:.3f}"
                    " s); cannot clear the fault",
                )
        for node, age in self._heartbeats.expired(now):
            raise DriveFault(node, 0, f"no heartbeat for {age:.3f} s; cannot clear the fault")
        with self._fault_lock:
            self._fault = None
            self.fault_at_sync = None
            self.quick_stop_at_sync = None
            for d in self._drives:
                d.fault_text, d.last_emcy, d.fault_tpdos = "", None, 0
                d.feedback = dataclasses.replace(d.feedback, fault="")
                d.reset_stream()
        return notes

    def home(
        self, sync: Callable[[], None] | None = None, timeout_s: float | None = None
    ) -> list[int]:
        """Home every drive with its 0x6098 method; return the actual positions after homing, in
        the group's order. Drives that are not enabled are enabled for homing and disabled again
        afterwards (the power state is left as found).

        ``sync`` sends one SYNC (and whatever else the caller's cycle needs) so TPDO feedback
        keeps coming; by default the group sends SYNCs itself at the configured period. The
        caller's loop must not send set-points meanwhile. The drives return to their configured
        mode afterwards (confirmed by 0x6061).
        """
        self._require_started()
        self._require_no_fault()
        self._sync_source = sync
        was_enabled = all(d.feedback.state is State.OPERATION_ENABLED for d in self._drives)
        try:
            for d in self._drives:
                for w in epos.homing_writes(d.cfg):
                    self._sdo_write(d, w)
                self._set_mode(d, Mode.HOMING)
            self._walk(State.OPERATION_ENABLED, STATE_STEP_TIMEOUT_S)
            with self._cycle_lock:
                for d in self._drives:
                    self._send_controlword(d, CW_ENABLE_OPERATION)
                    self._send_controlword(d, CW_ENABLE_OPERATION | CW_HOMING_START_BIT)
                start = self.sync_count
            limit = timeout_s or max(d.cfg.homing.timeout_s for d in self._drives)

            def homed(d: _Drive) -> bool:
                sw = d.feedback.statusword
                if sw & SW_HOMING_ERROR:
                    raise DriveFault(
                        d.id,
                        0,
                        f"homing error (statusword 0x{sw:04X}, bit 13), "
                        f"method {d.cfg.homing.method}",
                    )
                return bool(sw & SW_HOMING_ATTAINED and sw & SW_TARGET_REACHED)

            self._wait_for(self._drives, homed, limit, "homing", after_sync=start)
            with self._cycle_lock:
                for d in self._drives:
                    self._send_controlword(d, CW_ENABLE_OPERATION)
            for d in self._drives:
                self._set_mode(d, d.mode)
                d.reset_stream()
            after = self.sync_count
            self._wait_for(self._drives, lambda d: True, STATE_STEP_TIMEOUT_S, "feedback", after)
            if not was_enabled:
                self.disable_all()
            return [d.feedback.position_counts for d in self._drives]
        finally:
            self._sync_source = None

    def _set_mode(self, d: _Drive, mode: Mode) -> None:
        self._sdo_write(
            d,
            epos.SdoWrite(
                epos.MODES_OF_OPERATION, 0, struct.pack("<b", mode), "modes of operation"
            ),
        )
        deadline = self.clock() + STATE_STEP_TIMEOUT_S
        while True:
            shown = struct.unpack("<b", self._sdo_read(d, epos.MODES_DISPLAY, 0)[:1])[0]
            if shown == int(mode):
                return
            if self.clock() > deadline:
                raise RigTimeoutError(
                    f"node {d.id}: 0x6061 shows mode {shown}, not {int(mode)} ({mode.name}), "
                    f"{STATE_STEP_TIMEOUT_S} s after writing 0x6060"
                )
            time.sleep(self.period_s)

    def move_to(
        self, targets_counts: Sequence[int], timeout_s: float = MOVE_TIMEOUT_S
    ) -> list[int]:
        """Profile-position move of every drive to ``targets_counts`` (blocking, not for the
        loop's path): new set-point with bit 4, acknowledged by statusword bit 12, then wait for
        target reached (bit 10). Drives must be OPERATION ENABLED in mode ``pp``. Returns the
        actual positions."""
        self._require_started()
        self._require_no_fault()
        for d in self._drives:
            if d.mode is not Mode.PROFILE_POSITION:
                raise DriveFault(d.id, 0, f"move_to needs profile position mode, not {d.cfg.mode}")
            if d.feedback.state is not State.OPERATION_ENABLED:
                raise DriveFault(
                    d.id,
                    0,
                    f"move_to needs OPERATION ENABLED, not "
                    f"{d.feedback.state.value}: enable() first",
                )
        bits = CW_NEW_SETPOINT_BIT | CW_CHANGE_IMMEDIATELY_BIT
        with self._cycle_lock:
            for d, t in zip(self._drives, targets_counts, strict=True):
                d.controlword = CW_ENABLE_OPERATION
                self._send(
                    d.layout.setpoint.cob_id, pp_setpoint_payload(int(t), d.controlword | bits)
                )
                d.last_target, d.pp_pending = int(t), True
            start = self.sync_count
        self._wait_for(
            self._drives,
            lambda d: bool(d.feedback.statusword & SW_SETPOINT_ACK),
            SETPOINT_ACK_TIMEOUT_S,
            "set-point acknowledge",
            after_sync=start,
        )
        with self._cycle_lock:
            for d in self._drives:
                self._send(
                    d.layout.setpoint.cob_id, pp_setpoint_payload(d.last_target or 0, d.controlword)
                )
                d.pp_pending = False
            start = self.sync_count
        self._wait_for(
            self._drives,
            lambda d: (
                bool(d.feedback.statusword & SW_TARGET_REACHED)
                and not d.feedback.statusword & SW_SETPOINT_ACK
            ),
            timeout_s,
            "target reached",
            after_sync=start,
        )
        return [d.feedback.position_counts for d in self._drives]

    # ================================================================== shutdown
    def close(self) -> None:
        """Make the drives safe and close the bus: quick stop (if any drive may be moving), wait
        briefly for them to stop, disable voltage, disarm their heartbeat consumers, NMT
        pre-operational, stop the master heartbeat and the traffic log, shut the bus down.
        Works after a start-up that failed half way (SDO disable to every node that booted).
        Never raises for bus errors."""
        if self._closed:
            return
        try:
            self._make_safe()
        except Exception:  # closing must finish: log and carry on
            log.exception("making the drives safe failed")
        finally:
            self._closed = True
            self._hb_on = False
            self._watchdog_stop.set()
            if threading.current_thread() is not self._watchdog:
                self._watchdog.join(1.0)
            self.log_traffic(None)
            try:
                self.network.disconnect()
            except (can.CanError, OSError, RuntimeError) as exc:
                log.warning("closing the CAN bus: %s", exc)

    def _make_safe(self) -> None:
        bus_dead = self._fault is not None and self._fault.node == 0
        if self._started:
            moving = any(
                d.feedback.state in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE)
                for d in self._drives
            )
            if moving:
                self.quick_stop_all()
                deadline = self.clock() + CLOSE_SETTLE_S
                while (
                    not bus_dead
                    and self.clock() < deadline
                    and any(
                        d.feedback.state is State.OPERATION_ENABLED
                        or (
                            d.feedback.state is State.QUICK_STOP_ACTIVE
                            and d.cfg.quick_stop_option_code < 5
                        )
                        for d in self._drives
                    )
                ):
                    self._await_feedback(deadline - self.clock())
            self.disable_all()
        if bus_dead:
            return
        for d in self._drives:
            if not (d.present or d.booted.is_set()):
                continue
            d.node.sdo.RESPONSE_TIMEOUT = CLOSE_SDO_TIMEOUT_S
            if not self._started:
                # Start-up failed half way: PDOs may not run, so disable by SDO.
                self._best_effort(d, epos.CONTROLWORD, 0, controlword_payload(CW_DISABLE_VOLTAGE))
            self._best_effort(d, epos.HEARTBEAT_CONSUMER, 1, struct.pack("<I", 0))
        self._hb_on = False
        for d in self._drives:
            with contextlib.suppress(CommError):
                self._send(NMT_COB_ID, bytes((NMT_PRE_OPERATIONAL, d.id)))

    def _best_effort(self, d: _Drive, index: int, sub: int, data: bytes) -> None:
        try:
            d.node.sdo.download(index, sub, data)
        except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError, RuntimeError) as exc:
            log.warning("node %d: closing write 0x%04X:%02X failed (%s)", d.id, index, sub, exc)

    def __enter__(self) -> DriveGroup:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_drive_group(
    bus_cfg: CanBusConfig,
    drives: Sequence[DriveConfig],
    file: str = "",
    boot_timeout_s: float = BOOT_TIMEOUT_S,
) -> DriveGroup:
    """Open the bus ``bus_cfg`` names, boot and configure ``drives`` (nothing is enabled); the
    group is closed again (drives made safe) before any start-up error propagates."""
    group = DriveGroup(open_bus(bus_cfg), bus_cfg, drives, file=file)
    try:
        group.boot(boot_timeout_s)
        group.configure()
    except BaseException:
        group.close()
        raise
    return group


#: Kept for callers of earlier versions of this module.
rpdo_target_payload = target_payload
rpdo_controlword_payload = controlword_payload
parse_pvt_payload = epos.parse_pvt
configuration_writes = epos.configuration_writes
pdo_mapping_writes = epos.pdo_mapping_writes

__all__ = [
    "BOOT_TIMEOUT_S",
    "FAULT_RESET_TIMEOUT_S",
    "STATE_STEP_TIMEOUT_S",
    "DriveGroup",
    "Feedback",
    "GroupFault",
    "open_drive_group",
    "parse_tpdo_feedback",
]
