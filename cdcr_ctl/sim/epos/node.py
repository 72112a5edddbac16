"""A simulated maxon EPOS4/EPOS2 on canopen's LocalNode.

canopen gives the SDO server, the NMT slave, the heartbeat producer and the EMCY producer. This
module adds what LocalNode lacks, as a real drive does it:

- RPDOs applied through their mapping (synchronous ones at the next SYNC, event-driven ones on
  receipt), TPDOs sent through theirs (on every n-th SYNC, or on change), mapping changes refused
  with the CiA 301 abort codes while a PDO is valid;
- the CiA 402 state machine (controlword -> statusword), quick stop with option code 0x605A,
  halt, fault reset on the rising edge of bit 7;
- modes: cyclic synchronous position (EPOS4; targets interpolated over the SYNC period), profile
  position (trapezoidal moves, set-point handshake on bits 4/12, change immediately), homing
  (37/35 actual position; -1..-4 current threshold against a hard stop), interpolated position
  with the PVT buffer 0x20C1 (EPOS2), position mode 0x2062 (EPOS2);
- supervision: following error (0x6065 window for 0x6066 ms), software position limits,
  limit switches, the heartbeat consumer of the master (0x1016; the drive faults with EMCY 0x8130
  when the master goes silent), EMCY on every fault and an error reset EMCY on fault reset;
- a motor with encoder and gearbox under a position loop (:mod:`.plant`).

Time: on every SYNC the axis advances by one SYNC period (``advance_on_sync``, default):
:attr:`SimEpos.sync_period_s` when its owner set it, else the interpolation period 0x60C2; so a
run is reproducible frame for frame. :meth:`SimEpos.step` advances explicitly.

Lag, as on the real drive: the drive samples its actual position at the SYNC and applies the
set-point that came with it after; so the TPDO sent after SYNC k shows the motor as it was when
SYNC k came, before the target of SYNC k acted: one cycle of feedback lag
(:attr:`SimEpos.lag_cycles`, default 1; n > 1 holds each sample back n - 1 further SYNCs; 0 is
the old zero-lag drive whose TPDO already shows the target of its own SYNC).

Refusals, as on the real drive: every SDO or PDO write is checked against the project's limits
table of the family (:mod:`cdcr_ctl.drives.limits`, written from maxon's device descriptions):
a missing object, a read-only one, a wrong length or a value out of range is answered with the
abort code the drive gives.

Coupling a plant (the simulated rig): read :attr:`SimEpos.position_counts` (the actual position
the drive reports), set :attr:`SimEpos.load_torque_Nm` (torque at the gearbox output, + in the
+ count direction) or install :attr:`SimEpos.load_fn` ``(position_counts, velocity_counts_s) ->
torque N·m`` evaluated every integration sub-step; :meth:`SimEpos.displace` shifts the motor.

Fault injection: :meth:`inject_fault` (any EMCY code; :meth:`inject_following_error` 0x8611,
:meth:`inject_over_current` 0x2310), :attr:`emcy_enabled` (False: EMCY frames get lost),
:meth:`stop_heartbeat` / :meth:`start_heartbeat`,
:meth:`go_silent` (stops answering anything: bus off, unplugged) / :meth:`recover` (comes back
with EMCY 0x81FD), :meth:`enter_bus_off` / :meth:`recover_from_bus_off` (an EPOS going bus off
faults itself), :meth:`force_state` (a drive left enabled by a previous session).
Measurements for fault tests: :attr:`transitions` (every state change with its time and SYNC
count) and :attr:`last_target_change` (when the CSP target last changed).
"""

from __future__ import annotations

import collections
import logging
import math
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import can
import canopen
from canopen.objectdictionary import NUMBER_TYPES
from canopen.sdo.exceptions import SdoAbortedError

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import (
    CW_HALT_BIT,
    STATE_BITS,
    SW_FOLLOWING_COMMAND,
    SW_FOLLOWING_ERROR,
    SW_HOMING_ATTAINED,
    SW_HOMING_ERROR,
    SW_INTERNAL_LIMIT,
    SW_IP_ACTIVE,
    SW_POSITION_REFERENCED,
    SW_REMOTE,
    SW_SETPOINT_ACK,
    SW_TARGET_REACHED,
    SW_VOLTAGE_ENABLED,
    Mode,
    State,
)
from cdcr_ctl.drives.emcy import (
    BUS_OFF,
    FOLLOWING_ERROR,
    HEARTBEAT_ERROR,
    IP_MODE_ERROR,
    NEGATIVE_LIMIT_SWITCH,
    OVER_CURRENT,
    PDO_LENGTH_ERROR,
    POSITIVE_LIMIT_SWITCH,
    SOFTWARE_LIMIT,
    encode_emcy,
    error_register_for,
)
from cdcr_ctl.drives.limits import check_write, shipped_table
from cdcr_ctl.sim.epos.od import ACCEPTED_MODES, ERROR_HISTORY, IP_BUFFER_SIZE, build_od
from cdcr_ctl.sim.epos.plant import Motor, MotorParams, Profile, PvtBuffer

log = logging.getLogger(__name__)

# SDO abort codes (CiA 301)
ABORT_MAPPING_OBJECT = 0x06040041  # object cannot be mapped to the PDO
ABORT_MAPPING_LENGTH = 0x06040042  # mapped objects exceed the PDO length
ABORT_PARAMETER_INCOMPATIBLE = 0x06040043  # general parameter incompatibility
ABORT_VALUE_RANGE = 0x06090030  # value range of parameter exceeded

#: Homing with a current threshold: the current must stay above it this long (s).
HOMING_CURRENT_DWELL_S = 0.002
#: Velocity (counts/s) under which a profile move counts as at rest for "target reached".
AT_REST_COUNTS_S = 50.0
#: Objects whose value is the drive's live state (read through, never cached).
_LIVE = (
    epos.STATUSWORD,
    epos.POSITION_ACTUAL,
    epos.MODES_DISPLAY,
    epos.VELOCITY_ACTUAL,
    0x6062,
    0x603F,
    epos.ERROR_REGISTER,
)


#: SYNCs between the position sample and its TPDO plus one (see the module docstring).
DEFAULT_LAG_CYCLES = 1
#: Quick stop option code of a drive without 0x605A (the EPOS2: stop on the ramp, power off).
QUICK_STOP_OPTION_ABSENT = 2

#: State changes each simulated drive keeps for the fault-matrix measurements.
TRANSITIONS_KEPT = 256


@dataclass
class _Pdo:
    number: int
    cob_id: int
    transmission: int
    entries: list[tuple[int, int, int]]  # (index, subindex, bytes)
    counter: int = 0
    last: bytes | None = None
    pending: bytes | None = None  # synchronous RPDO data waiting for SYNC
    #: TPDO: per entry a function giving its bytes (live objects read straight, see _readers).
    readers: list[Callable[[], bytes]] | None = None


class SimEpos:
    """One simulated drive on ``network`` (a canopen Network over any python-can bus)."""

    def __init__(
        self,
        network: canopen.Network,
        node_id: int,
        kind: str = "epos4",
        motor: MotorParams | None = None,
    ) -> None:
        self.node_id = node_id
        self.kind = kind
        self.network = network
        self.node = canopen.LocalNode(node_id, build_od(node_id, kind))
        network.add_node(self.node)
        # Gate canopen's SDO server and NMT slave so a silent drive answers nothing.
        network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        network.unsubscribe(0, self.node.nmt.on_command)
        network.subscribe(self.node.sdo.rx_cobid, self._on_sdo)
        network.subscribe(0, self._on_nmt)
        network.subscribe(0x080, self._on_sync)
        self.motor = Motor(motor or MotorParams())
        self.cpr = self.motor.p.counts_per_rev
        self._lock = threading.RLock()
        self.last_target: int | None = None
        self.last_target_change: tuple[float, int] = (time.monotonic(), 0)
        self.state = State.SWITCH_ON_DISABLED
        self.mode = 0
        self.controlword = 0
        self.offset = 0.0  # reported position = raw encoder counts + offset
        self.profile = Profile()
        self.pvt = PvtBuffer(IP_BUFFER_SIZE)
        self._csp_from = 0.0  # CSP segment: from this demand to the target over one period
        self._csp_to = 0.0
        self._csp_t = 0.0
        self._step_period_s = 0.0  # 0x60C2 as of the running step() (s)
        self._pp_target: float | None = None
        self._setpoint_ack = False
        self._homing_phase = ""  # "", "search", "backoff", "done", "error"
        self._homing_dwell = 0.0
        self._backoff_to = 0.0
        self._homed = False
        self._ferr_s = 0.0
        self.following_error = False
        self.internal_limit = False
        self.error_code = 0
        self.error_register = 0
        #: External torque at the gearbox output (N·m, + in the + count direction).
        self.load_torque_Nm = 0.0
        #: Optional load: (position counts, velocity counts/s) -> output torque N·m, per sub-step.
        self.load_fn: Callable[[float, float], float] | None = None
        #: Advance the axis by one SYNC period on every SYNC.
        self.advance_on_sync = True
        #: Time between two SYNCs (s) as the owner knows it (a real drive runs on its own clock);
        #: None: the interpolation period 0x60C2.
        self.sync_period_s: float | None = None
        #: Feedback lag in SYNCs (module docstring): 1 as on the real drive.
        self.lag_cycles = DEFAULT_LAG_CYCLES
        self._samples: collections.deque[list[tuple[int, bytes]]] = collections.deque()
        #: The limits the drive enforces on writes (maxon's files, via the shipped table).
        self.limits = shipped_table(kind)
        self.silent = False
        self._rebooting = False
        #: Fault hook: False drops EMCY frames (the master must notice the FAULT statusword).
        self.emcy_enabled = True
        # statistics (tests and benchmarks read these)
        self.sync_count = 0
        self.sync_times_s: collections.deque[float] = collections.deque(maxlen=200_000)
        self.rpdo_count = 0
        self.missed_setpoints = 0
        self.max_following_error_counts = 0.0
        self.emcy_sent: list[int] = []
        self._setpoint_since_sync = False
        self._master_hb_cob: int | None = None
        self._master_hb_s: float | None = None
        self._consumer_ms = 0
        self._now: Callable[[], float] = time.monotonic
        self._params: dict[tuple[int, int], int] = {}
        self._rpdos: dict[int, _Pdo] = {}
        self._tpdos: list[_Pdo] = []
        self._pdo_dirty = True
        self.node.add_write_callback(self._on_write)
        self.node.add_read_callback(self._on_read)
        self._rebuild_pdos()

    # ================================================================== fault-matrix records
    @property
    def state(self) -> State:
        """CiA 402 state; every change is recorded in :attr:`transitions`."""
        return self._state

    @state.setter
    def state(self, new: State) -> None:
        old = self.__dict__.get("_state")
        self._state = new
        if new is not old:
            # (monotonic time s, SYNCs seen, new state): how fast a fault made the drive safe.
            self.__dict__.setdefault("transitions", collections.deque(maxlen=TRANSITIONS_KEPT))
            self.transitions.append((time.monotonic(), self.__dict__.get("sync_count", 0), new))

    def _record_target(self, target: int) -> None:
        """Remember when the CSP target last changed (time s, SYNCs): a halted master holds it."""
        if target != self.last_target:
            self.last_target = target
            self.last_target_change = (time.monotonic(), self.sync_count)

    # ================================================================== values
    def _value(self, index: int, sub: int = 0) -> int:
        """Present value of a numeric object (parameters cached until written: the axis reads
        them every sub-step)."""
        key = (index, sub)
        value = self._params.get(key)
        if value is None:
            obj = self.node._find_object(index, sub)
            value = int(obj.decode_raw(self.node.get_data(index, sub)))
            if index not in _LIVE:
                self._params[key] = value
        return value

    @property
    def position_counts(self) -> int:
        """Actual position the drive reports (0x6064), counts."""
        return round(self.motor.x + self.offset)

    @property
    def velocity_counts_s(self) -> float:
        return self.motor.v

    @property
    def current_A(self) -> float:
        return self.motor.i

    @property
    def demand_counts(self) -> float:
        """Position demand value (0x6062): the reference the position loop follows, counts."""
        return self.profile.x + self.offset

    @property
    def statusword(self) -> int:
        with self._lock:
            s = self.state
            sw = STATE_BITS.get(s, 0) | SW_REMOTE
            if s in (
                State.READY_TO_SWITCH_ON,
                State.SWITCHED_ON,
                State.OPERATION_ENABLED,
                State.QUICK_STOP_ACTIVE,
            ):
                sw |= SW_VOLTAGE_ENABLED
            mode = self.mode
            if mode == Mode.HOMING:
                if self._homing_phase == "done":
                    sw |= SW_HOMING_ATTAINED | SW_TARGET_REACHED
                elif self._homing_phase == "error":
                    sw |= SW_HOMING_ERROR
            elif self._at_target():
                sw |= SW_TARGET_REACHED
            if mode == Mode.PROFILE_POSITION and self._setpoint_ack:
                sw |= SW_SETPOINT_ACK
            if mode == Mode.INTERPOLATED_POSITION and self.pvt.active:
                sw |= SW_IP_ACTIVE
            if mode == Mode.CYCLIC_SYNC_POSITION and s is State.OPERATION_ENABLED:
                sw |= SW_FOLLOWING_COMMAND
            if (
                mode
                in (
                    Mode.CYCLIC_SYNC_POSITION,
                    Mode.PROFILE_POSITION,
                    Mode.POSITION_MODE,
                    Mode.INTERPOLATED_POSITION,
                )
                and self.following_error
            ):
                sw |= SW_FOLLOWING_ERROR
            if self.internal_limit:
                sw |= SW_INTERNAL_LIMIT
            if self._homed and self.kind == "epos4":
                sw |= SW_POSITION_REFERENCED
            return sw

    def _at_target(self) -> bool:
        if self.state is not State.OPERATION_ENABLED and self.state is not State.QUICK_STOP_ACTIVE:
            return False
        goal = self._pp_target if self.mode == Mode.PROFILE_POSITION else None
        if goal is None:
            goal = self.profile.x
        window = self._value(0x6067)
        return (
            abs(goal - self.motor.x) <= window
            and abs(self.motor.v) < AT_REST_COUNTS_S
            and (self.profile.v == 0.0)
        )

    def _on_read(self, index: int, subindex: int, od: object) -> int | None:
        if index not in _LIVE:
            return None
        if index == epos.STATUSWORD:
            return self.statusword
        if index == epos.POSITION_ACTUAL:
            return self.position_counts
        if index == epos.MODES_DISPLAY:
            return self.mode
        if index == epos.VELOCITY_ACTUAL:
            return round(self.motor.v * 60.0 / self.cpr)
        if index == 0x6062:
            return round(self.demand_counts)
        if index == 0x603F:
            return self.error_code
        if index == epos.ERROR_REGISTER:
            return self.error_register
        return None

    # ================================================================== object writes
    def _on_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        refusal = check_write(self.limits, index, subindex, bytes(data))
        if refusal is not None and self.limits.has(index, subindex):
            # Objects outside the table (the simulator's own extras) keep canopen's checks.
            log.info("node %d: refused %s", self.node_id, refusal.text)
            raise SdoAbortedError(refusal.code)
        self._apply_write(index, subindex, data)
        if getattr(od, "data_type", None) in NUMBER_TYPES:
            self._params[(index, subindex)] = int(od.decode_raw(data))  # type: ignore[attr-defined]

    def _apply_write(self, index: int, subindex: int, data: bytes) -> None:
        if 0x1400 <= index <= 0x1BFF:
            self._check_pdo_write(index, subindex, data)
            self._pdo_dirty = True
            return
        if index == epos.CONTROLWORD:
            self._controlword(struct.unpack("<H", data)[0])
        elif index == epos.MODES_OF_OPERATION:
            self._set_mode(struct.unpack("<b", data)[0])
        elif index == epos.TARGET_POSITION:
            self._target(struct.unpack("<i", data)[0])
        elif index == epos.EPOS2_POSITION_MODE_SETPOINT and self.kind == "epos2":
            self._position_mode_setpoint(struct.unpack("<i", data)[0])
        elif index == epos.EPOS2_IP_DATA_RECORD and self.kind == "epos2":
            self._pvt_point(bytes(data))
        elif index == epos.IP_DATA_CONFIGURATION and subindex == 6 and self.kind == "epos2":
            if data[0] == 0:
                with self._lock:
                    self.pvt.clear()
        elif index == epos.HEARTBEAT_CONSUMER and subindex == 1:
            self._watch_master(struct.unpack("<I", data)[0])
        elif (index, subindex) == (epos.INTERPOLATION_PERIOD, 1) and data[0] == 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # a zero interpolation period
        elif (index, subindex) == (0x1003, 0) and data[0] != 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # only 0 (clear the history) may be written

    def _check_pdo_write(self, index: int, sub: int, data: bytes) -> None:
        """Refuse what a real drive refuses: remapping a valid PDO, unmappable objects, too long."""
        comm = index if index < 0x1600 or 0x1800 <= index < 0x1A00 else index - 0x200
        if index in range(0x1600, 0x1604) or index in range(0x1A00, 0x1A04):
            if not self._value(comm, 1) & epos.PDO_DISABLED:
                raise SdoAbortedError(ABORT_PARAMETER_INCOMPATIBLE)
            if sub == 0:
                n = data[0]
                if n > 8:
                    raise SdoAbortedError(ABORT_VALUE_RANGE)
                bits = sum(self._value(index, s) & 0xFF for s in range(1, n + 1))
                if bits > 64:
                    raise SdoAbortedError(ABORT_MAPPING_LENGTH)
            else:
                (entry,) = struct.unpack("<I", data)
                obj_index, obj_sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
                try:
                    obj = self.node._find_object(obj_index, obj_sub)
                except SdoAbortedError:
                    raise SdoAbortedError(ABORT_MAPPING_OBJECT) from None
                if not obj.pdo_mappable or len(obj) != bits:
                    raise SdoAbortedError(ABORT_MAPPING_OBJECT)
                rx = index < 0x1A00
                if (rx and not obj.writable) or (not rx and not obj.readable):
                    raise SdoAbortedError(ABORT_MAPPING_OBJECT)

    # ================================================================== PDOs
    def _rebuild_pdos(self) -> None:
        """Read PDO communication and mapping parameters into fast tables; (re)subscribe RPDOs."""
        for cob in list(self._rpdos):
            self.network.unsubscribe(cob, self._on_rpdo)
        self._rpdos, self._tpdos = {}, []
        for i in range(4):
            for comm, mapping, rx in (
                (0x1400 + i, 0x1600 + i, True),
                (0x1800 + i, 0x1A00 + i, False),
            ):
                cob = self._value(comm, 1)
                if cob & epos.PDO_DISABLED:
                    continue
                entries = []
                for s in range(1, self._value(mapping, 0) + 1):
                    e = self._value(mapping, s)
                    entries.append((e >> 16, (e >> 8) & 0xFF, (e & 0xFF) // 8))
                pdo = _Pdo(i + 1, cob & 0x7FF, self._value(comm, 2), entries)
                if rx:
                    self._rpdos[pdo.cob_id] = pdo
                else:
                    self._tpdos.append(pdo)
        for cob in self._rpdos:
            self.network.subscribe(cob, self._on_rpdo)
        self._pdo_dirty = False

    def _operational(self) -> bool:
        return not self.silent and not self._rebooting and self.node.nmt.state == "OPERATIONAL"

    def _on_rpdo(self, can_id: int, data: bytearray, ts: float) -> None:
        if not self._operational():
            return
        if self._pdo_dirty:
            self._rebuild_pdos()
        pdo = self._rpdos.get(can_id)
        if pdo is None:
            return
        if len(data) < sum(n for _, _, n in pdo.entries):
            self._fault(PDO_LENGTH_ERROR)
            return
        self.rpdo_count += 1
        if pdo.transmission <= 240:
            pdo.pending = bytes(data)  # synchronous: applied at the next SYNC
        else:
            self._apply_rpdo(pdo, bytes(data))
            self._send_changed_tpdos()

    def _apply_rpdo(self, pdo: _Pdo, data: bytes) -> None:
        offset = 0
        for index, sub, n in pdo.entries:
            chunk = data[offset : offset + n]
            offset += n
            if index in (
                epos.TARGET_POSITION,
                epos.EPOS2_POSITION_MODE_SETPOINT,
                epos.EPOS2_IP_DATA_RECORD,
            ):
                self._setpoint_since_sync = True
            try:
                self.node.set_data(index, sub, chunk)
            except SdoAbortedError as exc:
                log.warning(
                    "node %d: RPDO write 0x%04X refused (0x%08X)", self.node_id, index, exc.code
                )

    def _tpdo_payload(self, pdo: _Pdo) -> bytes:
        readers = pdo.readers
        if readers is None:
            readers = pdo.readers = self._readers(pdo)
        return b"".join(read() for read in readers)

    def _readers(self, pdo: _Pdo) -> list[Callable[[], bytes]]:
        """Per TPDO entry, what ``node.get_data(index, sub)[:n]`` gives: for the live objects
        (statusword, actual position, ...) the read callback's value encoded by the object
        itself, without canopen's lookup per SYNC; for the rest canopen's get_data."""
        out: list[Callable[[], bytes]] = []
        for index, sub, n in pdo.entries:
            if index in _LIVE:
                obj = self.node._find_object(index, sub)

                def read(index: int = index, sub: int = sub, n: int = n, obj=obj) -> bytes:
                    return obj.encode_raw(self._on_read(index, sub, obj))[:n]

            else:

                def read(index: int = index, sub: int = sub, n: int = n) -> bytes:
                    return self.node.get_data(index, sub)[:n]

            out.append(read)
        return out

    def _send_changed_tpdos(self) -> None:
        """Event-driven TPDOs (type 254/255): sent when their data changed."""
        if not self._operational():
            return
        for pdo in self._tpdos:
            if pdo.transmission >= 254:
                payload = self._tpdo_payload(pdo)
                if payload != pdo.last:
                    pdo.last = payload
                    self._send(pdo.cob_id, payload)

    def _on_sync(self, can_id: int, data: bytearray, ts: float) -> None:
        if self.silent:
            return
        now = self._now()
        out: list[tuple[int, bytes]] = []
        with self._lock:
            self.sync_count += 1
            self.sync_times_s.append(now)
            if self._pdo_dirty:
                self._rebuild_pdos()
            operational = self._operational()
            lag = self.lag_cycles
            if operational and lag > 0:
                # The position (and statusword) latched at this SYNC, before its set-point acts.
                self._samples.append(self._sync_tpdos())
                if len(self._samples) >= lag:
                    out = self._samples.popleft()
            elif not operational:
                self._samples.clear()
            if operational:
                for pdo in self._rpdos.values():
                    if pdo.pending is not None:
                        pending, pdo.pending = pdo.pending, None
                        self._apply_rpdo(pdo, pending)
            if (
                self.state is State.OPERATION_ENABLED
                and self.mode in (Mode.CYCLIC_SYNC_POSITION, Mode.POSITION_MODE)
                and not self._setpoint_since_sync
                and self.sync_count > 1
            ):
                self.missed_setpoints += 1
            self._setpoint_since_sync = False
            if self.advance_on_sync:
                self.step(self.sync_period_s or self.interpolation_period_s)
            if operational and lag <= 0:
                out = self._sync_tpdos()
        for cob, payload in out:
            self._send(cob, payload)
        self._send_changed_tpdos()
        self.check_master_heartbeat(now)

    def _sync_tpdos(self) -> list[tuple[int, bytes]]:
        """The synchronous TPDOs due at this SYNC, with their data as of now (lock held)."""
        out: list[tuple[int, bytes]] = []
        for pdo in self._tpdos:
            if 1 <= pdo.transmission <= 240:
                pdo.counter += 1
                if pdo.counter >= pdo.transmission:
                    pdo.counter = 0
                    out.append((pdo.cob_id, self._tpdo_payload(pdo)))
            elif pdo.transmission == 0:
                payload = self._tpdo_payload(pdo)
                if payload != pdo.last:
                    pdo.last = payload
                    out.append((pdo.cob_id, payload))
        return out

    def _option(self, index: int, absent: int) -> int:
        """Value of an object the family may lack (EPOS2: 0x605A, 0x6066): ``absent`` then."""
        return self._value(index) if self.limits.has(index) else absent

    @property
    def interpolation_period_s(self) -> float:
        """0x60C2: value * 10^index s."""
        return self._value(epos.INTERPOLATION_PERIOD, 1) * 10.0 ** self._value(
            epos.INTERPOLATION_PERIOD, 2
        )

    # ================================================================== NMT and SDO gates
    def _on_sdo(self, can_id: int, data: bytearray, ts: float) -> None:
        if not self.silent and self.node.nmt.state != "STOPPED":
            self.node.sdo.on_request(can_id, data, ts)

    def _on_nmt(self, can_id: int, data: bytearray, ts: float) -> None:
        if self.silent or len(data) < 2:
            return
        cmd, nid = data[0], data[1]
        if nid not in (0, self.node_id):
            return
        self.node.nmt.on_command(can_id, data, ts)
        if cmd == 0x81:
            self.power_cycle()
        elif cmd == 0x82:
            self._reset_communication()
            self.boot()

    def power_cycle(self) -> None:
        """Reset node (NMT 0x81) or power off and on: application and communication objects
        back to their defaults, SWITCH ON DISABLED, the incremental encoder restarts at 0,
        boot-up message. Also a fault hook (a drive that restarts behind the master's back)."""
        self._rebooting = True  # no PDO is processed while the drive restarts
        with self._lock:
            self.state = State.SWITCH_ON_DISABLED
            self.controlword = 0
            self.mode = 0
            self._homed = False
            self.offset = -self.motor.x
            self._hold_here()
            for index in [i for i in self.node.data_store if i >= 0x2000]:
                del self.node.data_store[index]
            self._params.clear()
            self._reset_communication()
            self.boot()
            self._rebooting = False

    def _reset_communication(self) -> None:
        for index in [i for i in self.node.data_store if 0x1000 <= i < 0x2000]:
            del self.node.data_store[index]
        for key in [k for k in self._params if 0x1000 <= k[0] < 0x2000]:
            del self._params[key]
        self._watch_master(0)
        self._pdo_dirty = True

    def boot(self) -> None:
        """Power on: boot-up message, PRE-OPERATIONAL, heartbeat if 0x1017 says so."""
        self.node.nmt.send_command(0x82)  # -> INITIALISING, sends the boot-up message
        self.node.nmt.send_command(0x80)  # -> PRE-OPERATIONAL, heartbeat producer starts

    # ================================================================== CiA 402
    def _controlword(self, cw: int) -> None:
        with self._lock:
            old, self.controlword = self.controlword, cw
            s = self.state
            if s is State.FAULT:
                if cw & 0x80 and not old & 0x80:
                    self.state = State.SWITCH_ON_DISABLED
                    self.following_error = False
                    self.internal_limit = False
                    self.error_code = 0
                    self.error_register = 0
                    self._emcy(0x0000)
                return
            if s in (State.NOT_READY_TO_SWITCH_ON, State.FAULT_REACTION_ACTIVE):
                return
            new = s
            if cw & 0x02 == 0:  # disable voltage: transitions 7, 9, 10, 12
                new = State.SWITCH_ON_DISABLED
            elif cw & 0x06 == 0x02:  # quick stop: transitions 7, 10, 11
                new = (
                    State.QUICK_STOP_ACTIVE
                    if s is State.OPERATION_ENABLED
                    else (
                        State.SWITCH_ON_DISABLED
                        if s in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON)
                        else s
                    )
                )
            elif cw & 0x07 == 0x06:  # shutdown: transitions 2, 6, 8
                if s in (State.SWITCH_ON_DISABLED, State.SWITCHED_ON, State.OPERATION_ENABLED):
                    new = State.READY_TO_SWITCH_ON
            elif cw & 0x0F == 0x07:  # switch on / disable operation: transitions 3, 5
                if s in (State.READY_TO_SWITCH_ON, State.OPERATION_ENABLED):
                    new = State.SWITCHED_ON
            elif cw & 0x0F == 0x0F:  # enable operation: 4, 16 (and 3+4 from READY TO SWITCH ON)
                resume = s is State.QUICK_STOP_ACTIVE and self._quick_stop_option() >= 5
                if s in (State.SWITCHED_ON, State.READY_TO_SWITCH_ON) or resume:
                    new = State.OPERATION_ENABLED
            if new is not s:
                self._enter(new)
            if self.state is State.OPERATION_ENABLED:
                rising = cw & 0x10 and not old & 0x10
                if self.mode == Mode.HOMING and rising:
                    self._start_homing()
                elif self.mode == Mode.PROFILE_POSITION:
                    if rising and not self._setpoint_ack:
                        self._new_setpoint(cw)
                    elif not cw & 0x10:
                        self._setpoint_ack = False
                elif self.mode == Mode.INTERPOLATED_POSITION:
                    if rising and not self.pvt.active:
                        self.pvt.start(self.motor.x, 0.0)
                    elif not cw & 0x10 and self.pvt.active:
                        self.pvt.active = False
                        self.profile.set(self.profile.x, self.profile.v)

    def _enter(self, new: State) -> None:
        """State entry actions (lock held)."""
        old = self.state
        self.state = new
        if new is State.OPERATION_ENABLED and old is not State.OPERATION_ENABLED:
            self._hold_here()
        if new in (State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON, State.SWITCHED_ON):
            self.motor.reset_controller()
            self.pvt.clear()
            self._pp_target = None
            self._setpoint_ack = False

    def _hold_here(self) -> None:
        """Make the present position the reference (enable, mode change)."""
        self.profile.set(self.motor.x, 0.0)
        self._csp_from = self._csp_to = self.motor.x
        self._csp_t = 0.0
        self._pp_target = None
        self.pvt.clear()
        self._ferr_s = 0.0

    def _set_mode(self, mode: int) -> None:
        if mode not in ACCEPTED_MODES[self.kind]:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        with self._lock:
            self.mode = mode
            self._hold_here()
            self._homing_phase = ""

    def _limits(self) -> tuple[int, int]:
        return (
            self._value(epos.SOFTWARE_POSITION_LIMIT, 1),
            self._value(epos.SOFTWARE_POSITION_LIMIT, 2),
        )

    def _target(self, target: int) -> None:
        with self._lock:
            if self.mode != Mode.CYCLIC_SYNC_POSITION or self.state is not State.OPERATION_ENABLED:
                return  # profile position reads 0x607A at the set-point edge
            if self._controlword_halted():
                return
            self._record_target(target)
            lo, hi = self._limits()
            if not lo <= target <= hi:
                self.internal_limit = True
                self._fault(SOFTWARE_LIMIT[self.kind])
                return
            self._csp_from = self.profile.x
            self._csp_to = target - self.offset
            self._csp_t = 0.0

    def _position_mode_setpoint(self, value: int) -> None:
        with self._lock:
            if self.mode != Mode.POSITION_MODE or self.state is not State.OPERATION_ENABLED:
                return
            lo, hi = self._limits()
            if not lo <= value <= hi:
                self._fault(SOFTWARE_LIMIT[self.kind])
                return
            self.profile.set(value - self.offset, 0.0)

    def _new_setpoint(self, cw: int) -> None:
        target = self._value(epos.TARGET_POSITION)
        if cw & 0x40:  # relative
            target += round(
                (self._pp_target if self._pp_target is not None else self.profile.x) + self.offset
            )
        lo, hi = self._limits()
        clamped = min(max(target, lo), hi)
        self.internal_limit = clamped != target
        self._pp_target = clamped - self.offset
        self._setpoint_ack = True

    def _pvt_point(self, data: bytes) -> None:
        parsed = epos.parse_pvt(data)
        if parsed is None:
            return
        pos, rpm, t_ms = parsed
        with self._lock:
            if not self.pvt.push(pos - self.offset, rpm * self.cpr / 60.0, t_ms / 1000.0):
                self._fault(IP_MODE_ERROR)  # buffer overflow

    def _quick_stop_option(self) -> int:
        return self._option(epos.QUICK_STOP_OPTION, QUICK_STOP_OPTION_ABSENT)

    def _controlword_halted(self) -> bool:
        return bool(self.controlword & CW_HALT_BIT)

    def _start_homing(self) -> None:
        method = self._value(epos.HOMING_METHOD)
        self._homed = False
        self.profile.set(self.motor.x, 0.0)
        if method in (35, 37):
            self._set_home_here()
        elif method in (-1, -2, -3, -4):
            self._homing_phase, self._homing_dwell = "search", 0.0
        else:
            log.warning("node %d: homing method %d is not simulated", self.node_id, method)
            self._homing_phase = "error"

    def _homing_objects(self) -> tuple[int, int, int]:
        if self.kind == "epos4":
            return (
                epos.EPOS4_HOME_OFFSET_MOVE,
                epos.EPOS4_HOME_POSITION,
                epos.EPOS4_HOMING_CURRENT_THRESHOLD,
            )
        return epos.EPOS2_HOME_OFFSET, epos.EPOS2_HOME_POSITION, epos.EPOS2_HOMING_CURRENT_THRESHOLD

    def _set_home_here(self) -> None:
        _, home, _ = self._homing_objects()
        self.offset = self._value(home) - self.motor.x
        self._csp_from = self._csp_to = self.profile.x
        self._homing_phase = "done"
        self._homed = True

    # ================================================================== time
    def step(self, dt_s: float) -> None:
        """Advance the drive (set-point generators, supervision, motor) by ``dt_s`` seconds."""
        with self._lock:
            p = self.motor.p
            n = max(1, math.ceil(dt_s / p.substep_s - 1e-9))
            h = dt_s / n
            self._step_period_s = self.interpolation_period_s  # objects change between steps
            for _ in range(n):
                self._substep(h)

    def _rpm(self, index: int, sub: int = 0) -> float:
        """A velocity/acceleration object in rpm (or rpm/s) as counts/s (or counts/s²)."""
        return self._value(index, sub) * self.cpr / 60.0

    def _substep(self, h: float) -> None:
        """Motor from t to t + h on the reference of t; then the reference moves on to t + h
        (so the controller compares reference and position of the same instant)."""
        s = self.state
        powered = s in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE)
        prof = self.profile
        if self.load_fn is not None:
            tau = self.load_fn(self.motor.x + self.offset, self.motor.v)
        else:
            tau = self.load_torque_Nm
        self.motor.substep(h, prof.x, prof.v, prof.a, powered, tau)
        if s is State.QUICK_STOP_ACTIVE:
            stopped = prof.stop(self._rpm(epos.QUICK_STOP_DECELERATION), h)
            at_rest = stopped and abs(self.motor.v) < AT_REST_COUNTS_S
            if at_rest and self._quick_stop_option() in (1, 2):
                self._enter(State.SWITCH_ON_DISABLED)
                powered = False
        elif s is State.OPERATION_ENABLED:
            if self._controlword_halted() and self.mode != Mode.HOMING:
                prof.stop(self._rpm(epos.PROFILE_DECELERATION), h)
                self._csp_from = self._csp_to = prof.x
            elif self.mode == Mode.CYCLIC_SYNC_POSITION:
                period = self._step_period_s
                self._csp_t = min(self._csp_t + h, period)
                v = (self._csp_to - self._csp_from) / period
                x = self._csp_from + v * self._csp_t
                prof.a = 0.0
                prof.x, prof.v = x, (v if self._csp_t < period else 0.0)
            elif self.mode == Mode.PROFILE_POSITION:
                if self._pp_target is not None:
                    prof.move(
                        self._pp_target,
                        self._rpm(epos.PROFILE_VELOCITY),
                        self._rpm(epos.PROFILE_ACCELERATION),
                        self._rpm(epos.PROFILE_DECELERATION),
                        h,
                    )
            elif self.mode == Mode.HOMING:
                self._homing_substep(h)
            elif self.mode == Mode.INTERPOLATED_POSITION and self.pvt.active:
                sample = self.pvt.sample(h)
                if sample is None:
                    prof.set(*self.pvt.hold)
                    self.pvt.active = False
                    self._fault(IP_MODE_ERROR)  # buffer underflow
                    return
                prof.a = (sample[1] - prof.v) / h
                prof.x, prof.v = sample
        if powered:
            self._supervise(h)

    def _homing_substep(self, h: float) -> None:
        prof = self.profile
        method = self._value(epos.HOMING_METHOD)
        offset_obj, _, threshold_obj = self._homing_objects()
        acc = self._rpm(epos.HOMING_ACCELERATION)
        if self._homing_phase == "search":
            direction = 1.0 if method in (-1, -3) else -1.0
            prof.ramp_velocity(direction * self._rpm(epos.HOMING_SPEEDS, 1), acc, h)
            if abs(self.motor.i) * 1000.0 >= self._value(threshold_obj):
                self._homing_dwell += h
                if self._homing_dwell >= HOMING_CURRENT_DWELL_S:
                    self._homing_phase = "backoff"
                    self._backoff_to = self.motor.x - direction * self._value(offset_obj)
                    prof.set(self.motor.x, 0.0)
                    self.motor.reset_controller()
            else:
                self._homing_dwell = 0.0
        elif self._homing_phase == "backoff":
            speed = self._rpm(epos.HOMING_SPEEDS, 2)
            if (
                prof.move(self._backoff_to, speed, acc, acc, h)
                and abs(self.motor.v) < AT_REST_COUNTS_S
            ):
                self._set_home_here()

    def _supervise(self, h: float) -> None:
        err = abs(self.profile.x - self.motor.x)
        if self.mode == Mode.CYCLIC_SYNC_POSITION:
            self.max_following_error_counts = max(self.max_following_error_counts, err)
        window = self._value(epos.FOLLOWING_ERROR_WINDOW)
        searching = self.mode == Mode.HOMING and self._homing_phase == "search"
        if window != 0xFFFFFFFF and err > window and not searching:
            self.following_error = True
            self._ferr_s += h
            if self._ferr_s * 1000.0 >= self._option(epos.FOLLOWING_ERROR_TIMEOUT, 0):
                self._fault(FOLLOWING_ERROR)
                return
        else:
            self.following_error = False
            self._ferr_s = 0.0
        lo, hi = self._limits()
        actual = self.motor.x + self.offset
        if not lo - 1 <= actual <= hi + 1 and self.mode != Mode.HOMING:
            self.internal_limit = True
            self._fault(SOFTWARE_LIMIT[self.kind])
            return
        switches = self.motor.p.limit_switches_counts
        if switches is not None:
            if self.motor.x <= switches[0]:
                self._fault(NEGATIVE_LIMIT_SWITCH[self.kind])
            elif self.motor.x >= switches[1]:
                self._fault(POSITIVE_LIMIT_SWITCH[self.kind])

    # ================================================================== faults
    def _fault(self, code: int) -> None:
        """Fault reaction: power stage off at once, FAULT, EMCY ``code``."""
        with self._lock:
            if self.state is State.FAULT:
                return
            self.state = State.FAULT
            self.motor.i = 0.0  # the power stage goes off at once
            self.error_code = code
            self.error_register = error_register_for(code)
            self.pvt.clear()
            self._pp_target = None
            self._setpoint_ack = False
            self.motor.reset_controller()
            self.profile.set(self.motor.x, 0.0)
            n_hist = ERROR_HISTORY
            history = [self.node.data_store.get(0x1003, {}).get(s) for s in range(1, n_hist)]
            store = self.node.data_store.setdefault(0x1003, {})
            store[1] = struct.pack("<I", code)
            for s, old in enumerate(history, start=2):
                if old is not None:
                    store[s] = old
            store[0] = bytes((min(n_hist, 1 + sum(o is not None for o in history)),))
            # Still under the lock: the EMCY goes out before any TPDO showing FAULT.
            self._emcy(code)

    def _emcy(self, code: int) -> None:
        self.emcy_sent.append(code)
        if not self.silent and self.emcy_enabled:
            self._send(0x080 + self.node_id, encode_emcy(code))

    def _send(self, cob_id: int, data: bytes) -> None:
        """Send a frame; a node stepped without a bus (tests, plant studies) sends nothing."""
        try:
            self.network.send_message(cob_id, data)
        except (RuntimeError, can.CanError) as exc:
            log.debug("node %d: 0x%03X not sent (%s)", self.node_id, cob_id, exc)

    # ------------------------------------------------------------------ master heartbeat
    def _watch_master(self, value: int) -> None:
        master, ms = (value >> 16) & 0x7F, value & 0xFFFF
        if self._master_hb_cob is not None:
            self.network.unsubscribe(self._master_hb_cob, self._on_master_hb)
            self._master_hb_cob = None
        self._consumer_ms = ms
        self._master_hb_s = None  # monitoring starts with the first heartbeat (CiA 301)
        if master and ms:
            self._master_hb_cob = 0x700 + master
            self.network.subscribe(self._master_hb_cob, self._on_master_hb)

    def _on_master_hb(self, can_id: int, data: bytearray, ts: float) -> None:
        if not self.silent:
            self._master_hb_s = self._now()

    def check_master_heartbeat(self, now: float | None = None) -> None:
        """Heartbeat consumer: fault with EMCY 0x8130 when the master's heartbeat is overdue."""
        last = self._master_hb_s
        if last is None or not self._consumer_ms or self.silent:
            return
        now = self._now() if now is None else now
        if now - last > self._consumer_ms / 1e3:
            self._master_hb_s = None
            self._fault(HEARTBEAT_ERROR)

    # ================================================================== hooks
    def inject_fault(self, code: int) -> None:
        """Fault hook: the drive faults with EMCY ``code`` (power stage off)."""
        self._fault(code)

    inject_emcy = inject_fault

    def inject_following_error(self) -> None:
        self._fault(FOLLOWING_ERROR)

    def inject_over_current(self) -> None:
        self._fault(OVER_CURRENT)

    def stop_heartbeat(self) -> None:
        """Fault hook: stop producing heartbeats (everything else keeps working)."""
        self.node.nmt.stop_heartbeat()

    def start_heartbeat(self) -> None:
        self.node.nmt.start_heartbeat(self._value(epos.HEARTBEAT_PRODUCER))

    def go_silent(self) -> None:
        """Fault hook: answer nothing at all (bus off, cable unplugged): no SDO, PDO, EMCY,
        heartbeat; incoming frames are ignored, the motor keeps its last state."""
        self.silent = True
        self.node.nmt.stop_heartbeat()

    bus_off = go_silent

    def enter_bus_off(self) -> None:
        """Fault hook: the drive's CAN controller goes bus off. As an EPOS does, the drive
        faults (power stage off, error 0x81FD recorded; the EMCY cannot get out) and answers
        nothing until :meth:`recover`, which resumes its heartbeat and reports the fault."""
        self.go_silent()
        self._fault(BUS_OFF)

    def recover_from_bus_off(self) -> None:
        """Back on the bus after :meth:`enter_bus_off`: heartbeats resume, EMCY 0x81FD goes out
        (the drive stays in FAULT until a fault reset)."""
        self.silent = False
        self.start_heartbeat()
        self._emcy(BUS_OFF)

    def recover(self) -> None:
        """Back on the bus after a bus off: fault with EMCY 0x81FD, heartbeats resume."""
        self.silent = False
        self.start_heartbeat()
        self._fault(BUS_OFF)

    def force_state(self, state: State, mode: int | None = None) -> None:
        """Test hook: put the drive in ``state`` (e.g. left OPERATION ENABLED by a previous
        session), holding its present position."""
        with self._lock:
            if mode is not None:
                self.mode = mode
            self.state = state
            self._hold_here()

    def displace(self, counts: float) -> None:
        """Shift the motor by ``counts`` (slip, a knock); the position loop sees it as an error."""
        with self._lock:
            self.motor.x += counts
