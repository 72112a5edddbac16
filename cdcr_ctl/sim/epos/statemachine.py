"""The simulated EPOS's CiA 402 state machine: controlword -> state (quick stop with option
code 0x605A, halt, fault reset on the rising edge of bit 7), the set-point entry of each mode
(CSP targets, profile-position handshake, PVT points, position mode), homing start, and the
fault reaction with its EMCY and error history 0x1003.

A mixin of :class:`~cdcr_ctl.sim.epos.node.SimEpos` (the state lives on the node).
"""

from __future__ import annotations

import logging
import struct

from canopen.sdo.exceptions import SdoAbortedError

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import CW_HALT_BIT, Mode, State
from cdcr_ctl.drives.emcy import IP_MODE_ERROR, SOFTWARE_LIMIT, encode_emcy, error_register_for
from cdcr_ctl.sim.epos.objects import ABORT_VALUE_RANGE
from cdcr_ctl.sim.epos.od import ACCEPTED_MODES, ERROR_HISTORY

#: One logger for the whole simulated node (the name it had before the node was split up).
log = logging.getLogger("cdcr_ctl.sim.epos.node")


# Module globals: read faster than the enums' attributes.
_OPERATION_ENABLED = State.OPERATION_ENABLED
_CSP = Mode.CYCLIC_SYNC_POSITION

#: Quick stop option code of a drive without 0x605A (the EPOS2: stop on the ramp, power off).
QUICK_STOP_OPTION_ABSENT = 2


class _StateMachine:
    """CiA 402 state machine and fault reaction of :class:`~cdcr_ctl.sim.epos.node.SimEpos`."""

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
        """0x607D min and max (kept in :attr:`_derived` until a parameter changes)."""
        value = self._derived.get("limits")
        if value is None:
            value = (
                self._value(epos.SOFTWARE_POSITION_LIMIT, 1),
                self._value(epos.SOFTWARE_POSITION_LIMIT, 2),
            )
            self._derived["limits"] = value
        return value

    def _target(self, target: int) -> None:
        with self._lock:
            if self.mode != _CSP or self._state is not _OPERATION_ENABLED:
                return  # profile position reads 0x607A at the set-point edge
            if self.controlword & CW_HALT_BIT:
                return  # halted (_controlword_halted without the call)
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
