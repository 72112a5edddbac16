"""The drive group's facade: :class:`DriveGroup`, the one object the loop and the CLI hold. It
owns the state and the threads, builds the parts from its mixins (wire, supervision,
start-up, sequences, cycle) and makes the drives safe on close; :func:`open_drive_group`.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import struct
import threading
import time
from collections.abc import Callable, Sequence

import can
import canopen
from can.interfaces.slcan import slcanBus
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from cdcr_ctl.config.drives import CanBusConfig, DriveConfig
from cdcr_ctl.drives import epos
from cdcr_ctl.drives.busload import BusLoad, check_drives_bus_load
from cdcr_ctl.drives.canbus import open_bus
from cdcr_ctl.drives.cia402 import CW_DISABLE_VOLTAGE, State
from cdcr_ctl.drives.epos import controlword_payload
from cdcr_ctl.drives.group.common import (
    BOOT_TIMEOUT_S,
    CLOSE_SDO_TIMEOUT_S,
    CLOSE_SETTLE_S,
    FRAME_RING,
    NMT_COB_ID,
    NMT_PRE_OPERATIONAL,
    SDO_TIMEOUT_S,
    SEND_TIMEOUT_S,
    TPDO_MISSES,
    WATCHDOG_PERIOD_S,
    GroupFault,
    _Drive,
)
from cdcr_ctl.drives.group.cycle import _Cycle
from cdcr_ctl.drives.group.sequences import _Sequences
from cdcr_ctl.drives.group.startup import _Startup
from cdcr_ctl.drives.group.supervision import _Supervision
from cdcr_ctl.drives.group.traffic import DeferredTrafficLog
from cdcr_ctl.drives.group.wire import _Network, _RxTap, _Wire
from cdcr_ctl.drives.heartbeat import HeartbeatConsumer
from cdcr_ctl.drives.plan import check_writes, object_table, planned_writes
from cdcr_ctl.drives.slcan import SlcanBus
from cdcr_ctl.errors import CommError, RigError

#: One logger for the whole group (the name it had before the group was split up).
log = logging.getLogger("cdcr_ctl.drives.group")


class DriveGroup(_Wire, _Supervision, _Startup, _Sequences, _Cycle):
    """The drives of one rig, in the order given (the caller's order, e.g. cable order).

    ``bus`` is injected (any python-can bus); the group owns it from here and shuts it down on
    :meth:`close`. Use as a context manager: exit quick-stops and disables the drives, stops the
    master heartbeat and closes the bus, even if start-up failed half way. ``clock`` (default
    ``time.monotonic``) stamps feedback and measures the bus's own timeouts (boot, SDO, feedback
    ages). ``watch_clock`` (default: ``clock``) is the time the drives live on: their heartbeats
    are stamped and checked on it, the master heartbeat is due on it (:meth:`produce_heartbeat`),
    and the sequences' waits for the drives' state (each 402 step, fault reset, homing, moves,
    the settle on close) are measured on it, with a backstop of
    :data:`~cdcr_ctl.drives.group.common.WALL_BACKSTOP_FACTOR` times each timeout on ``clock``.
    A caller whose drives run on simulated time (the lock-step rig) passes that time, so a host
    that stalls while simulated time stands still trips and times out nothing.
    ``file`` names the config file in errors. The cyclic PDO set must fit
    ``bus_cfg.max_bus_load`` (ConfigError otherwise).
    """

    def __init__(
        self,
        bus: can.BusABC,
        bus_cfg: CanBusConfig,
        drives: Sequence[DriveConfig],
        clock: Callable[[], float] = time.monotonic,
        *,
        watch_clock: Callable[[], float] | None = None,
        file: str = "",
        react_to_faults: bool = True,
    ) -> None:
        self.bus_cfg = bus_cfg
        self.clock = clock
        self.watch_clock = clock if watch_clock is None else watch_clock
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
        self._traffic: DeferredTrafficLog | None = None
        #: When the traffic log's writer may take the interpreter lock (the daemon gives it the
        #: control loop's "between cycles"); None: whenever it has frames. Read when a log starts.
        self.traffic_quiet: Callable[[], bool] | None = None
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
        self._hb_lock = threading.Lock()

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
        # A bus that can hand frames over without a Message (SlcanBus) does so for the cyclic
        # TPDOs and the drives' heartbeats, in its receiving thread.
        set_frame_hook = getattr(bus, "set_frame_hook", None)
        if callable(set_frame_hook):
            set_frame_hook(
                [*self._by_tpdo, *(0x700 + d.id for d in self._drives)], self._on_hooked_frame
            )
        self.network.connect()
        #: How often the watchdog thread wakes (s): master heartbeat, idle heartbeat checks. A
        #: rig whose heartbeat periods are long (the lock-step simulator's) may wake it less
        #: often: each wake takes the interpreter lock from the loop thread.
        self.watchdog_period_s = WATCHDOG_PERIOD_S
        self._watchdog_stop = threading.Event()
        self._watchdog = threading.Thread(target=self._watch, name="drives-watchdog", daemon=True)
        self._watchdog.start()

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
                deadline = self._deadline(CLOSE_SETTLE_S)
                while (
                    not bus_dead
                    and deadline.expired() is None
                    and any(
                        d.feedback.state is State.OPERATION_ENABLED
                        or (
                            d.feedback.state is State.QUICK_STOP_ACTIVE
                            and d.cfg.quick_stop_option_code < 5
                        )
                        for d in self._drives
                    )
                ):
                    self._await_feedback(deadline.left_s())
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
