"""The simulated EPOS's PDO service and its NMT/SDO gates: RPDOs applied through their mapping
(synchronous ones at the next SYNC), TPDOs built through theirs (every n-th SYNC with the
feedback lag, or on change), the per-SYNC work, NMT commands, boot and power cycle.

A mixin of :class:`~cdcr_ctl.sim.epos.node.SimEpos` (the state lives on the node).
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can
from canopen.nmt import NmtSlave
from canopen.objectdictionary import INTEGER32, INTEGER_TYPES, NUMBER_TYPES
from canopen.sdo.exceptions import SdoAbortedError

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import Mode, State
from cdcr_ctl.drives.emcy import PDO_LENGTH_ERROR
from cdcr_ctl.sim.epos.objects import _LIVE, _Objects

#: Objects whose write by RPDO counts as the SYNC's set-point.
_SETPOINTS = frozenset(
    (epos.TARGET_POSITION, epos.EPOS2_POSITION_MODE_SETPOINT, epos.EPOS2_IP_DATA_RECORD)
)

#: The CSP target's store key, its mapping entry and its encoding (INTEGER32).
_TARGET_KEY = (epos.TARGET_POSITION, 0)
_TARGET_ENTRIES = [(epos.TARGET_POSITION, 0, 4)]
_I32 = struct.Struct("<i")
# Module globals: read faster than the enums' attributes.
_OPERATION_ENABLED = State.OPERATION_ENABLED
#: Modes whose set-point comes every SYNC (a SYNC without one counts as missed).
_SYNC_SETPOINT_MODES = (Mode.CYCLIC_SYNC_POSITION, Mode.POSITION_MODE)

#: One logger for the whole simulated node (the name it had before the node was split up).
log = logging.getLogger("cdcr_ctl.sim.epos.node")


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
    #: TPDO of live numeric objects only: (one ``struct`` for the payload, per entry the value's
    #: getter and its range), see :meth:`_PdoService._packer`; False: none (use ``readers``).
    packer: tuple[struct.Struct, list[Callable[[], int]], list[tuple[Any, Any]]] | bool | None = (
        None
    )
    #: RPDO: per entry its dictionary object (looked up once; None: not in the dictionary).
    objects: list[Any] | None = None
    #: Bytes the mapping covers (the sum of the entries' sizes).
    size: int = 0
    #: RPDO of the target position alone: what :meth:`_PdoService._write_target` needs (see
    #: :meth:`_PdoService._target_plan`); None: not looked at yet; False: not such an RPDO.
    target_plan: tuple | bool | None = None

    def __post_init__(self) -> None:
        self.size = sum(n for _, _, n in self.entries)


class _PdoService:
    """PDOs, SYNC, NMT and SDO gates of :class:`~cdcr_ctl.sim.epos.node.SimEpos`."""

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
        #: The event-driven TPDOs (type 254/255), see :meth:`_send_changed_tpdos`.
        self._event_tpdos = [p for p in self._tpdos if p.transmission >= 254]
        self._pdo_dirty = False

    def _operational(self) -> bool:
        return not self.silent and not self._rebooting and self.node.nmt.state == "OPERATIONAL"

    def _on_rpdo(self, can_id: int, data: bytearray, ts: float) -> None:
        if self.silent or self._rebooting or self.node.nmt.state != "OPERATIONAL":
            return  # not _operational() (without the call)
        if self._pdo_dirty:
            self._rebuild_pdos()
        pdo = self._rpdos.get(can_id)
        if pdo is None:
            return
        if len(data) < pdo.size:
            self._fault(PDO_LENGTH_ERROR)
            return
        self.rpdo_count += 1
        if pdo.transmission <= 240:
            pdo.pending = bytes(data)  # synchronous: applied at the next SYNC
        else:
            self._apply_rpdo(pdo, bytes(data))
            self._send_changed_tpdos()

    def _apply_rpdo(self, pdo: _Pdo, data: bytes) -> None:
        plan = pdo.target_plan
        if plan is None:
            plan = pdo.target_plan = self._target_plan(pdo)
        if plan is not False and self.fast_paths and self._write_target(plan, data):
            return
        objects = pdo.objects
        if objects is None:
            objects = pdo.objects = [self._find_or_none(i, s) for i, s, _ in pdo.entries]
        offset = 0
        for (index, sub, n), obj in zip(pdo.entries, objects, strict=True):
            chunk = data[offset : offset + n]
            offset += n
            if index in _SETPOINTS:
                self._setpoint_since_sync = True
            try:
                if obj is None:
                    self.node.set_data(index, sub, chunk)
                else:
                    self._set_data(obj, index, sub, chunk)
            except SdoAbortedError as exc:
                log.warning(
                    "node %d: RPDO write 0x%04X refused (0x%08X)", self.node_id, index, exc.code
                )

    def _target_plan(self, pdo: _Pdo) -> tuple | bool:
        """For an RPDO mapping the target position alone (the CSP set-point RPDO) in a node
        whose write callbacks are canopen's NMT slave's (it acts on 0x1017 only) and
        :meth:`_Objects._on_write`, and whose limits table has the target as a writable
        INTEGER32: ``(callbacks, table, limit, low, high)`` for :meth:`_write_target`; else
        False."""
        if pdo.entries != _TARGET_ENTRIES:
            return False
        obj = self._find_or_none(*_TARGET_KEY)
        if obj is None or obj.data_type != INTEGER32 or len(obj) != 32:
            return False
        callbacks = tuple(self.node._write_callbacks)
        expected = ((NmtSlave.on_write, self.node.nmt), (_Objects._on_write, self))
        if len(callbacks) != len(expected):
            return False
        for cb, (func, owner) in zip(callbacks, expected, strict=True):
            if (
                getattr(cb, "__func__", None) is not func
                or getattr(cb, "__self__", None) is not owner
            ):
                return False
        table = self.limits
        limit = table.get(*_TARGET_KEY)
        if limit is None or not limit.writable or limit.dtype != INTEGER32:
            return False
        return callbacks, table, limit, limit.low, limit.high

    def _write_target(self, plan: tuple, data: bytes) -> bool:
        """The target-position RPDO ``data`` written as :meth:`_set_data` and
        :meth:`_Objects._on_write` write it when the limits table accepts it (the set-point
        flag, :meth:`_target`, the cached parameter, the stored bytes, in that order), without
        the generic checks per frame. False (nothing done) when the node or its table changed
        since :meth:`_target_plan` or the value is out of range: the general path then."""
        (nmt_cb, own_cb), table, limit, low, high = plan
        callbacks = self.node._write_callbacks
        if (
            self.limits is not table
            or len(callbacks) != 2
            or callbacks[0] is not nmt_cb
            or callbacks[1] is not own_cb
            or table.get(*_TARGET_KEY) is not limit
        ):
            return False
        chunk = data[:4]
        (value,) = _I32.unpack(chunk)
        if (low is not None and value < low) or (high is not None and value > high):
            return False  # refused: the general path logs it
        self._setpoint_since_sync = True
        self._target(value)
        self._params[_TARGET_KEY] = value
        self.node.data_store.setdefault(epos.TARGET_POSITION, {})[0] = chunk
        return True

    def _find_or_none(self, index: int, sub: int) -> Any:
        """The dictionary object ``index:sub``, or None when there is none (then canopen's
        ``set_data`` gives its abort on every write, as before)."""
        try:
            return self.node._find_object(index, sub)
        except SdoAbortedError:
            return None

    def _set_data(self, obj: Any, index: int, sub: int, data: bytes) -> None:
        """canopen's ``LocalNode.set_data(index, sub, data)`` for the object ``obj`` found once
        (:attr:`_Pdo.objects`): the same length check, write callbacks and store, without the
        dictionary lookup per frame."""
        node = self.node
        if obj.data_type in NUMBER_TYPES and 8 * len(data) != len(obj):
            raise SdoAbortedError(0x06070010)
        for callback in node._write_callbacks:
            callback(index=index, subindex=sub, od=obj, data=data)
        node.data_store.setdefault(index, {})[sub] = bytes(data)

    def _tpdo_payload(self, pdo: _Pdo) -> bytes:
        packer = pdo.packer
        if packer is None:
            packer = pdo.packer = self._packer(pdo)
        if packer is not False:
            st, getters, bounded = packer  # type: ignore[misc]
            if len(getters) == 2:  # the feedback TPDOs (without a list comprehension's frame)
                get0, get1 = getters
                values = [get0(), get1()]
            else:
                values = [get() for get in getters]
            for k, lo, hi in bounded:
                v = values[k]
                if (lo is not None and v < lo) or (hi is not None and v > hi):
                    break  # canopen warns about it: let it (and refuse what does not fit)
            else:
                try:
                    return st.pack(*values)
                except struct.error:
                    pass
        readers = pdo.readers
        if readers is None:
            readers = pdo.readers = self._readers(pdo)
        return b"".join(read() for read in readers)

    def _packer(self, pdo: _Pdo) -> tuple[struct.Struct, list[Callable[[], int]], list] | bool:
        """A TPDO mapping only whole live integer objects (statusword, actual position, ...)
        built with one ``struct`` from the values :meth:`_on_read` gives: the bytes canopen's
        ``encode_raw`` makes of each (little-endian, the object's own type), joined. False
        when any entry is not such an object (the per-entry :meth:`_readers` then). Returned:
        the struct, per entry its value's getter, and ``(entry, min, max)`` of the entries
        whose object has a range."""
        formats, getters, bounded = [], [], []
        for k, (index, sub, n) in enumerate(pdo.entries):
            if index not in _LIVE:
                return False
            obj = self._find_or_none(index, sub)
            st = None if obj is None else obj.STRUCT_TYPES.get(obj.data_type)
            if not isinstance(st, struct.Struct) or obj.data_type not in INTEGER_TYPES:
                return False
            if st.size != n or len(st.format.lstrip("<")) != 1:
                return False
            formats.append(st.format.lstrip("<"))

            def get(index: int = index, sub: int = sub, obj: Any = obj) -> int:
                return int(self._on_read(index, sub, obj))

            # The two objects of every feedback TPDO read straight (what _on_read gives them).
            direct = {
                epos.STATUSWORD: self._statusword,
                epos.POSITION_ACTUAL: self._position_counts,
            }
            getters.append(direct.get(index, get))
            if obj.min is not None or obj.max is not None:
                bounded.append((k, obj.min, obj.max))
        return struct.Struct("<" + "".join(formats)), getters, bounded

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
        if not self._event_tpdos or not self._operational():
            return
        for pdo in self._event_tpdos:
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
            # _operational() without the call
            operational = (
                not self.silent and not self._rebooting and self.node.nmt.state == "OPERATIONAL"
            )
            lag = self.lag_cycles
            samples = self._samples
            if operational and lag > 0:
                # The position (and statusword) latched at this SYNC, before its set-point acts.
                if lag == 1 and not samples:
                    out = self._sync_tpdos()  # appended and taken out again at once
                else:
                    samples.append(self._sync_tpdos())
                    if len(samples) >= lag:
                        out = samples.popleft()
            elif not operational:
                samples.clear()
            if operational:
                for pdo in self._rpdos.values():
                    if pdo.pending is not None:
                        pending, pdo.pending = pdo.pending, None
                        self._apply_rpdo(pdo, pending)
            if (
                self._state is _OPERATION_ENABLED
                and self.mode in _SYNC_SETPOINT_MODES
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
        if self._event_tpdos:  # (_send_changed_tpdos has nothing to do without one)
            self._send_changed_tpdos()
        if self._master_hb_s is not None:  # (nor check_master_heartbeat before a heartbeat)
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
            self._derived.clear()
            self._reset_communication()
            self.boot()
            self._rebooting = False

    def _reset_communication(self) -> None:
        for index in [i for i in self.node.data_store if 0x1000 <= i < 0x2000]:
            del self.node.data_store[index]
        for key in [k for k in self._params if 0x1000 <= k[0] < 0x2000]:
            del self._params[key]
        self._derived.clear()
        self._watch_master(0)
        self._pdo_dirty = True

    def boot(self) -> None:
        """Power on: boot-up message, PRE-OPERATIONAL, heartbeat if 0x1017 says so."""
        self.node.nmt.send_command(0x82)  # -> INITIALISING, sends the boot-up message
        self.node.nmt.send_command(0x80)  # -> PRE-OPERATIONAL, heartbeat producer starts

    def _send(self, cob_id: int, data: bytes) -> None:
        """Send a frame; a node stepped without a bus (tests, plant studies) sends nothing."""
        try:
            self.network.send_message(cob_id, data)
        except (RuntimeError, can.CanError) as exc:
            log.debug("node %d: 0x%03X not sent (%s)", self.node_id, cob_id, exc)
