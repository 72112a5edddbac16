"""The drive group's wire: every frame sent (one at a time or a cycle's burst) and received
(the dispatcher that decodes the feedback TPDOs with one ``struct`` unpack and hands the rest
to canopen), the frame ring, the CAN traffic log and the blocking SDO reads and writes.

A mixin of :class:`~cdcr_ctl.drives.group.facade.DriveGroup` (the state lives on the group).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import State, state_of
from cdcr_ctl.drives.epos import parse_tpdo_feedback
from cdcr_ctl.drives.group.common import FAULT_TPDOS, Feedback, _Drive, format_frames
from cdcr_ctl.drives.group.traffic import DeferredTrafficLog
from cdcr_ctl.errors import CommError, DriveFault

#: One logger for the whole group (the name it had before the group was split up).
log = logging.getLogger("cdcr_ctl.drives.group")


_FAULT = State.FAULT  # (a module global: read faster than the enum's attribute)


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


class _Wire:
    """Send and receive for :class:`~cdcr_ctl.drives.group.facade.DriveGroup`."""

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
        """One frame to the traffic log: queued for its writer thread
        (:class:`~.traffic.DeferredTrafficLog`: no formatting, no lock on the send and receive
        paths). A write error (disk full) stops the traffic log and is kept in
        :attr:`traffic_failure`; it is not a bus fault and never reaches the caller."""
        traffic = self._traffic
        if traffic is not None:
            traffic.on_message_received(msg)

    @property
    def traffic_logging(self) -> bool:
        """Whether a traffic log is running."""
        return self._traffic is not None

    def _traffic_failed(self, text: str) -> None:
        """(the traffic log's writer thread) Its log stopped on a write error."""
        self.traffic_failure = text
        traffic = self._traffic
        if traffic is not None and traffic.failed:
            self._traffic = None

    def _on_rx_error(self, exc: Exception) -> None:
        """The bus listener failed to receive (adapter unplugged, interface down): latch a bus
        fault at once; the listener keeps trying, no faster than its cycle, until close."""
        where = f"CAN {self.bus_cfg.interface}:{self.bus_cfg.channel}"
        self._latch("bus:rx", 0, 0, f"{where}: receiving failed ({exc})")
        if not self._closed:
            time.sleep(_Network.NOTIFIER_CYCLE)

    def _on_hooked_frame(self, can_id: int, data: bytes, timestamp: float) -> None:
        """A frame straight from the bus's receive path (:meth:`SlcanBus.set_frame_hook`): a
        feedback TPDO or a drive's heartbeat."""
        if can_id in self._by_tpdo:
            self._on_tpdo_frame(can_id, data, timestamp)
            return
        self._frames.append((self.clock(), "rx", can_id, data))
        try:
            if self._traffic is not None:
                msg = can.Message(
                    timestamp=timestamp, arbitration_id=can_id, data=data, is_extended_id=False
                )
                self._log_frame(msg)
            self._on_heartbeat(can_id, bytearray(data), timestamp)
        except Exception:  # the bus's receive path must go on
            log.exception("handling CAN frame 0x%03X failed", can_id)

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
        if state is _FAULT and self._started:
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
                # The ASC writer directly: ``can.Logger`` scans the installed packages' entry
                # points for writer plugins on every call (2-7 ms of interpreter time measured,
                # at every run's start, in the loop's process); the same class results.
                if Path(path).suffix.lower() == ".asc":
                    logger: can.Listener = can.ASCWriter(str(path))
                else:
                    logger = can.Logger(str(path))
                quiet = getattr(self, "traffic_quiet", None)
                self._traffic = DeferredTrafficLog(logger, self._traffic_failed, quiet, tap)
                self.traffic_failure = None

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
