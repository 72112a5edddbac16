"""A simulated maxon EPOS4/EPOS2 on canopen's LocalNode.

The SDO server, NMT slave, heartbeat producer and EMCY producer are canopen's; this module adds
what LocalNode lacks: received RPDOs applied through their mapping, TPDOs sent on SYNC through
theirs, the CiA 402 state machine, a motor position loop stepped on every SYNC (deterministic:
no wall-clock thread moves the motor), following-error and software-limit supervision, the
heartbeat consumer of the master (0x1016) that faults the drive when the master goes silent, and
fault-injection hooks for tests and the simulated rig.
"""

from __future__ import annotations

import collections
import logging
import math
import struct
import threading
import time
from collections.abc import Callable

import canopen
from canopen.sdo.exceptions import SdoAbortedError

from cdcr_ctl.drives.cia402 import (
    CW_HALT_BIT,
    SW_FOLLOWING_ERROR,
    SW_HOMING_ATTAINED,
    SW_TARGET_REACHED,
    Mode,
    State,
)
from cdcr_ctl.sim.epos.od import build_od

log = logging.getLogger(__name__)

_STATE_BITS = {
    State.NOT_READY_TO_SWITCH_ON: 0x00,
    State.SWITCH_ON_DISABLED: 0x40,
    State.READY_TO_SWITCH_ON: 0x21,
    State.SWITCHED_ON: 0x23,
    State.OPERATION_ENABLED: 0x27,
    State.QUICK_STOP_ACTIVE: 0x07,
    State.FAULT_REACTION_ACTIVE: 0x0F,
    State.FAULT: 0x08,
}
#: Encoder increments per motor revolution (rpm -> counts/s for profile moves).
COUNTS_PER_REV = 4096
#: Points the EPOS2 interpolation buffer holds.
IP_BUFFER_POINTS = 64
#: Time constant of the simulated position loop (s): the motor follows the target this fast.
POSITION_LOOP_TAU_S = 0.0015


class SimEpos:
    """One simulated drive on ``network`` (a canopen Network over any python-can bus)."""

    def __init__(
        self,
        network: canopen.Network,
        node_id: int,
        kind: str = "epos4",
        encoder_counts_per_rev: int = 2048,
    ) -> None:
        self.node_id = node_id
        self.kind = kind
        self.node = canopen.LocalNode(node_id, build_od(node_id, kind))
        network.add_node(self.node)
        self.network = network
        self.state = State.SWITCH_ON_DISABLED
        self.mode = 0
        self.controlword = 0
        self.position = 0.0  # counts, float inside, reported rounded
        self.target = 0
        self._pending_target: int | None = None
        self.homing_attained = False
        self.following_error = False
        self.sync_count = 0
        self.last_sync_s: float | None = None
        #: Arrival times of every SYNC (s, monotonic) when a benchmark asks for them (a list).
        self.sync_times: list[float] | None = None
        self.emcy_sent: list[int] = []
        self.silent = False
        self.external_disturbance = 0.0
        self.encoder_counts_per_rev = encoder_counts_per_rev
        # Interpolated position (EPOS2 PVT): buffered points (position, velocity counts/s, time s)
        # and the segment being run (p0, v0, p1, v1, T, elapsed).
        self.ip_buffer: collections.deque[tuple[float, float, float]] = collections.deque(
            maxlen=IP_BUFFER_POINTS
        )
        self._ip_seg: list[float] | None = None
        self._ip_vel = 0.0
        self._master_hb_s: float | None = None
        self._lock = threading.RLock()
        self._now: Callable[[], float] = time.monotonic
        self.node.add_write_callback(self._on_write)
        self.node.add_read_callback(self._on_read)
        network.subscribe(0x080, self._on_sync)
        network.subscribe(0x000, self._on_nmt)
        for i in range(4):
            network.subscribe(self._rpdo_cob(i), self._rpdo_handler(i))
        self._hb_consumer_cob: int | None = None

    # ------------------------------------------------------------------ boot / NMT
    def boot(self) -> None:
        """Power on: boot-up message, PRE-OPERATIONAL, heartbeat if 0x1017 says so."""
        self.node.nmt.send_command(0x82)  # reset communication -> boot-up message
        self.node.nmt.send_command(0x80)  # -> PRE-OPERATIONAL, heartbeat producer starts

    def _on_nmt(self, can_id: int, data: bytearray, ts: float) -> None:
        if self.silent or len(data) < 2:
            return
        cmd, nid = data[0], data[1]
        if nid not in (0, self.node_id):
            return
        if cmd in (0x81, 0x82):
            if cmd == 0x81:
                with self._lock:
                    self.state = State.SWITCH_ON_DISABLED
                    self.controlword = 0
            self.boot()

    # ------------------------------------------------------------------ object access
    def _on_read(self, index: int, subindex: int, od: object) -> int | None:
        with self._lock:
            if index == 0x6041:
                return self.statusword
            if index == 0x6064:
                return round(self.position)
            if index == 0x6061:
                return self.mode
            if index == 0x6040:
                return self.controlword
        return None

    def _on_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        if index == 0x6040:
            self._controlword(struct.unpack("<H", data)[0])
        elif index == 0x6060:
            mode = struct.unpack("<b", data)[0]
            if mode not in (1, 3, 6, 7, 8, 9, 10, -1, -2, -3) or (
                self.kind == "epos2" and mode == 8
            ):
                raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
            with self._lock:
                self.mode = mode
                self.homing_attained = False
        elif index == 0x607A:
            self._set_target(struct.unpack("<i", data)[0])
        elif index == 0x1016 and subindex == 1:
            (value,) = struct.unpack("<I", data)
            self._watch_master(value)

    def _value(self, index: int, sub: int = 0) -> int:
        """Present value of an object, decoded with its dictionary data type."""
        obj = self.node._find_object(index, sub)
        return int(obj.decode_raw(self.node.get_data(index, sub)))

    # ------------------------------------------------------------------ PDOs
    def _rpdo_cob(self, i: int) -> int:
        return (0x200, 0x300, 0x400, 0x500)[i] + self.node_id

    def _rpdo_handler(self, i: int) -> Callable[[int, bytearray, float], None]:
        def handler(can_id: int, data: bytearray, ts: float) -> None:
            if self.silent or self.node.nmt.state != "OPERATIONAL":
                return
            cob = self._value(0x1400 + i, 1)
            if cob & 0x8000_0000 or (cob & 0x7FF) != can_id:
                return
            offset = 0
            for sub in range(1, self._value(0x1600 + i, 0) + 1):
                entry = self._value(0x1600 + i, sub)
                index, bits = entry >> 16, entry & 0xFF
                size = bits // 8
                if offset + size > len(data):
                    self._emcy(0x8210)  # PDO length error
                    return
                chunk = bytes(data[offset : offset + size])
                offset += size
                if index == 0x6040:
                    self._controlword(struct.unpack("<H", chunk)[0])
                elif index == 0x20C1:
                    pos = struct.unpack_from("<i", chunk)[0]
                    rpm = int.from_bytes(chunk[4:7], "little", signed=True)
                    v = rpm * self.encoder_counts_per_rev / 60.0
                    with self._lock:
                        self.ip_buffer.append((float(pos), v, chunk[7] / 1000.0))
                elif index == 0x607A:
                    (t,) = struct.unpack("<i", chunk)
                    if self._value(0x1400 + i, 2) <= 240:
                        self._pending_target = t  # synchronous: applied at the next SYNC
                    else:
                        self._set_target(t)
                else:
                    self.node.data_store.setdefault(index, {})[entry >> 8 & 0xFF] = chunk

        return handler

    def _tpdo_payload(self, i: int) -> bytes | None:
        cob = self._value(0x1800 + i, 1)
        n = self._value(0x1A00 + i, 0)
        if cob & 0x8000_0000 or n == 0:
            return None
        out = b""
        for sub in range(1, n + 1):
            entry = self._value(0x1A00 + i, sub)
            index, s, bits = entry >> 16, entry >> 8 & 0xFF, entry & 0xFF
            out += self.node.get_data(index, s)[: bits // 8]
        return out

    def _on_sync(self, can_id: int, data: bytearray, ts: float) -> None:
        if self.silent:
            return
        now = self._now()
        if self.sync_times is not None:
            self.sync_times.append(now)
        with self._lock:
            dt = 0.001 if self.last_sync_s is None else min(max(now - self.last_sync_s, 0.0), 0.1)
            self.last_sync_s = now
            self.sync_count += 1
            if self._pending_target is not None:
                self._set_target(self._pending_target)
                self._pending_target = None
            self.step(dt)
        self._check_master(now)
        if self.node.nmt.state != "OPERATIONAL":
            return
        for i in range(4):
            if self._value(0x1800 + i, 2) in range(1, 241):
                payload = self._tpdo_payload(i)
                if payload is not None:
                    self.network.send_message(self._value(0x1800 + i, 1) & 0x7FF, payload)

    # ------------------------------------------------------------------ CiA 402
    @property
    def statusword(self) -> int:
        sw = _STATE_BITS.get(self.state, 0) | 0x0200  # bit 9 remote
        if self.state in (State.OPERATION_ENABLED, State.SWITCHED_ON, State.QUICK_STOP_ACTIVE):
            sw |= 0x0010  # voltage enabled
        if abs(self.target - self.position) < 2:
            sw |= SW_TARGET_REACHED
        if self.mode == Mode.HOMING and self.homing_attained:
            sw |= SW_HOMING_ATTAINED
        if self.mode in (Mode.CYCLIC_SYNC_POSITION, Mode.PROFILE_POSITION) and self.following_error:
            sw |= SW_FOLLOWING_ERROR
        return sw

    def _controlword(self, cw: int) -> None:
        with self._lock:
            old, self.controlword = self.controlword, cw
            s = self.state
            if s is State.FAULT:
                if cw & 0x80 and not old & 0x80:
                    self.state = State.SWITCH_ON_DISABLED
                    self.following_error = False
                    self._emcy(0x0000)  # error reset
                return
            if cw & 0x82 == 0x00:
                self.state = State.SWITCH_ON_DISABLED
            elif cw & 0x86 == 0x02:
                if s is State.OPERATION_ENABLED:
                    # Quick stop option 2: ramp down on the quick stop ramp, then SWITCH ON
                    # DISABLED; the position loop holds the stop point.
                    self.target = round(self.position)
                    self.state = State.SWITCH_ON_DISABLED
                else:
                    self.state = State.SWITCH_ON_DISABLED
            elif cw & 0x87 == 0x06:
                if s in (State.SWITCH_ON_DISABLED, State.SWITCHED_ON, State.OPERATION_ENABLED):
                    self.state = State.READY_TO_SWITCH_ON
            elif cw & 0x8F == 0x07:
                if s in (State.READY_TO_SWITCH_ON, State.OPERATION_ENABLED):
                    self.state = State.SWITCHED_ON
            elif cw & 0x8F == 0x0F and s in (State.SWITCHED_ON, State.QUICK_STOP_ACTIVE):
                self.state = State.OPERATION_ENABLED
                self.target = round(self.position)
                self._pending_target = None
            if self.state is State.OPERATION_ENABLED:
                if self.mode == Mode.HOMING and cw & 0x10 and not old & 0x10:
                    self._home()
                if self.mode == Mode.PROFILE_POSITION and cw & 0x10 and not old & 0x10:
                    self.target = self._value(0x607A)

    def _set_target(self, t: int) -> None:
        lo, hi = self._value(0x607D, 1), self._value(0x607D, 2)
        if not lo <= t <= hi:
            self._fault(0x8A82)  # software position limit
            return
        with self._lock:
            # 0x607A holds the latest target (profile position takes it on the bit-4 edge).
            self.node.data_store.setdefault(0x607A, {})[0] = struct.pack("<i", t)
            if self.mode == Mode.CYCLIC_SYNC_POSITION and self.state is State.OPERATION_ENABLED:
                self.target = t

    def _home(self) -> None:
        method = self._value(0x6098)
        offset = self._value(0x607C)
        if method in (37, 35):
            # Actual position: the present position becomes the home position (+ offset).
            self.position = float(offset)
        else:
            # Current-threshold and switch methods: the simulator has no end stop; it moves a
            # little, "hits" the threshold and sets home there.
            self.position = float(offset)
        self.target = round(self.position)
        self.homing_attained = True

    def step(self, dt: float) -> None:
        """Advance the motor by ``dt`` seconds (called on SYNC)."""
        if self.state is not State.OPERATION_ENABLED or self.controlword & CW_HALT_BIT:
            self.position += self.external_disturbance
            return
        if self.mode == Mode.PROFILE_POSITION:
            vmax = self._value(0x6081) * COUNTS_PER_REV / 60.0
            err = self.target - self.position
            self.position += math.copysign(min(abs(err), vmax * dt), err)
        elif self.mode == Mode.INTERPOLATED_POSITION and self.controlword & 0x10:
            self._ip_step(dt)
        elif self.mode == Mode.CYCLIC_SYNC_POSITION:
            a = math.exp(-dt / POSITION_LOOP_TAU_S)
            self.position = self.target - (self.target - self.position) * a
        self.position += self.external_disturbance
        window = self._value(0x6065)
        if window and abs(self.target - self.position) > window:
            self.following_error = True
            self._fault(0x8611)

    def _ip_step(self, dt: float) -> None:
        """PVT: cubic Hermite from the present point to the next buffered one over its time."""
        left = dt
        while left > 0:
            if self._ip_seg is None:
                if not self.ip_buffer:
                    self._ip_vel = 0.0
                    return  # buffer underflow: hold
                p1, v1, T = self.ip_buffer.popleft()
                self._ip_seg = [self.target, self._ip_vel, p1, v1, max(T, 1e-4), 0.0]
            p0, v0, p1, v1, T, t = self._ip_seg
            t = min(t + left, T)
            left -= t - self._ip_seg[5]
            u = t / T
            h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
            h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
            self.target = round(h00 * p0 + h10 * T * v0 + h01 * p1 + h11 * T * v1)
            self._ip_seg[5] = t
            if t >= T:
                self.target, self._ip_vel, self._ip_seg = round(p1), v1, None
        self.position = float(self.target)

    def _fault(self, code: int) -> None:
        with self._lock:
            if self.state is State.FAULT:
                return
            self.state = State.FAULT
        self._emcy(code)

    def _emcy(self, code: int) -> None:
        self.emcy_sent.append(code)
        if not self.silent:
            self.node.emcy.send(code, 0x01 if code else 0x00)

    # ------------------------------------------------------------------ master heartbeat
    def _watch_master(self, value: int) -> None:
        master, ms = (value >> 16) & 0x7F, value & 0xFFFF
        if self._hb_consumer_cob is not None:
            self.network.unsubscribe(self._hb_consumer_cob, self._on_master_hb)
            self._hb_consumer_cob = None
        self._consumer_ms = ms
        if master and ms:
            self._hb_consumer_cob = 0x700 + master
            self.network.subscribe(self._hb_consumer_cob, self._on_master_hb)

    def _on_master_hb(self, can_id: int, data: bytearray, ts: float) -> None:
        self._master_hb_s = self._now()

    def _check_master(self, now: float) -> None:
        if self._master_hb_s is None or not getattr(self, "_consumer_ms", 0):
            return
        if now - self._master_hb_s > self._consumer_ms / 1e3:
            self._master_hb_s = None
            self._fault(0x8130)

    def check_master_heartbeat(self) -> None:
        """Heartbeat consumer check without SYNC (the master may have stopped sending both)."""
        self._check_master(self._now())

    # ------------------------------------------------------------------ fault injection
    def inject_emcy(self, code: int) -> None:
        """Fault with EMCY ``code`` (e.g. 0x8611 following error, 0x2310 over-current)."""
        self._fault(code)

    def stop_heartbeat(self) -> None:
        """Stop producing heartbeats (everything else keeps working)."""
        self.node.nmt.stop_heartbeat()

    def go_silent(self) -> None:
        """Stop answering anything: no SDO, PDO, heartbeat (adapter unplugged, bus off)."""
        self.silent = True
        self.node.nmt.stop_heartbeat()
        self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
