"""The simulated EPOS's object dictionary as the drive serves it: live objects (statusword,
actual position, mode display, ...) read through from the axis, parameters cached until
written, and every write checked against the family's limits table and applied (controlword,
mode, targets, PVT points, PDO parameters refused with the CiA 301 abort codes).

A mixin of :class:`~cdcr_ctl.sim.epos.node.SimEpos` (the state lives on the node).
"""

from __future__ import annotations

import logging
import struct

from canopen.objectdictionary import NUMBER_TYPES
from canopen.sdo.exceptions import SdoAbortedError

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import (
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
from cdcr_ctl.drives.limits import check_write

#: One logger for the whole simulated node (the name it had before the node was split up).
log = logging.getLogger("cdcr_ctl.sim.epos.node")


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

# Module globals (read faster than the enums' attributes) for the statusword.
_OPERATION_ENABLED = State.OPERATION_ENABLED
_QUICK_STOP_ACTIVE = State.QUICK_STOP_ACTIVE
_CSP, _PP, _IP, _HOMING = (
    Mode.CYCLIC_SYNC_POSITION,
    Mode.PROFILE_POSITION,
    Mode.INTERPOLATED_POSITION,
    Mode.HOMING,
)
#: Statusword bits of OPERATION ENABLED with remote and voltage enabled.
_ENABLED_BITS = STATE_BITS[_OPERATION_ENABLED] | SW_REMOTE | SW_VOLTAGE_ENABLED
#: ... and in cyclic synchronous position (following the command).
_CSP_ENABLED_BITS = _ENABLED_BITS | SW_FOLLOWING_COMMAND
#: States that report "voltage enabled".
_VOLTAGE_STATES = (
    State.READY_TO_SWITCH_ON,
    State.SWITCHED_ON,
    _OPERATION_ENABLED,
    _QUICK_STOP_ACTIVE,
)
#: Modes that report a following error in the statusword.
_FOLLOWING_MODES = (_CSP, _PP, Mode.POSITION_MODE, _IP)

#: The objects :attr:`_derived`'s values are computed from (interpolation period:
#: :attr:`_Objects.interpolation_period_s`; software position limits: ``_limits``): a write to
#: one of them empties it. A new derived value must add its objects here.
_DERIVED_FROM = frozenset((epos.INTERPOLATION_PERIOD, epos.SOFTWARE_POSITION_LIMIT))


class _Objects:
    """Object reads and writes of :class:`~cdcr_ctl.sim.epos.node.SimEpos`."""

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

    def _position_counts(self) -> int:
        return round(self.motor.x + self.offset)

    #: Actual position the drive reports (0x6064), counts.
    position_counts = property(_position_counts)

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

    def _statusword(self) -> int:
        with self._lock:
            s = self._state
            mode = self.mode
            if s is _OPERATION_ENABLED and mode == _CSP:
                # The steady CSP case (what _state_bits gives it, without the call): _at_target()
                # with the demand as the goal, no homing, profile-position or interpolation bits.
                motor, prof = self.motor, self.profile
                sw = _CSP_ENABLED_BITS
                if (
                    abs(prof.x - motor.x) <= self._value(0x6067)
                    and abs(motor.v) < AT_REST_COUNTS_S
                    and prof.v == 0.0
                ):
                    sw |= SW_TARGET_REACHED
                if self.following_error:
                    sw |= SW_FOLLOWING_ERROR
            else:
                sw = self._state_bits(s, mode)
            if self.internal_limit:
                sw |= SW_INTERNAL_LIMIT
            if self._homed and self.kind == "epos4":
                sw |= SW_POSITION_REFERENCED
            return sw

    def _state_bits(self, s: State, mode: int) -> int:
        """The statusword bits of state ``s`` in ``mode`` (all but internal limit and position
        referenced; lock held)."""
        if s is _OPERATION_ENABLED:
            sw = _ENABLED_BITS
            if mode == _CSP:
                sw |= SW_FOLLOWING_COMMAND
        else:
            sw = STATE_BITS.get(s, 0) | SW_REMOTE
            if s in _VOLTAGE_STATES:
                sw |= SW_VOLTAGE_ENABLED
        if mode == _HOMING:
            if self._homing_phase == "done":
                sw |= SW_HOMING_ATTAINED | SW_TARGET_REACHED
            elif self._homing_phase == "error":
                sw |= SW_HOMING_ERROR
        elif self._at_target():
            sw |= SW_TARGET_REACHED
        if mode == _PP and self._setpoint_ack:
            sw |= SW_SETPOINT_ACK
        if mode == _IP and self.pvt.active:
            sw |= SW_IP_ACTIVE
        if self.following_error and mode in _FOLLOWING_MODES:
            sw |= SW_FOLLOWING_ERROR
        return sw

    #: The statusword (0x6041) the drive reports now.
    statusword = property(_statusword)

    def _at_target(self) -> bool:
        s = self._state
        if s is not _OPERATION_ENABLED and s is not _QUICK_STOP_ACTIVE:
            return False
        goal = self._pp_target if self.mode == _PP else None
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
        if index in _DERIVED_FROM:
            # Only these feed :attr:`_derived`; a set-point (every SYNC) leaves it as it is.
            self._derived.clear()

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

    def _option(self, index: int, absent: int) -> int:
        """Value of an object the family may lack (EPOS2: 0x605A, 0x6066): ``absent`` then."""
        return self._value(index) if self.limits.has(index) else absent

    @property
    def interpolation_period_s(self) -> float:
        """0x60C2: value * 10^index s (kept in :attr:`_derived` until a parameter changes)."""
        value = self._derived.get("interpolation_period_s")
        if value is None:
            value = self._value(epos.INTERPOLATION_PERIOD, 1) * 10.0 ** self._value(
                epos.INTERPOLATION_PERIOD, 2
            )
            self._derived["interpolation_period_s"] = value
        return value
