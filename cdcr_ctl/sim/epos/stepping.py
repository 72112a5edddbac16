"""The simulated EPOS in time: the axis advanced in sub-steps (set-point generators of each mode,
quick stop and halt ramps, homing against a hard stop, the motor of :mod:`.plant`), the
supervision on every sub-step (following error, software limits, limit switches) and the
heartbeat consumer of the master (0x1016).

A mixin of :class:`~cdcr_ctl.sim.epos.node.SimEpos` (the state lives on the node).
"""

from __future__ import annotations

import math

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import Mode, State
from cdcr_ctl.drives.emcy import (
    FOLLOWING_ERROR,
    HEARTBEAT_ERROR,
    IP_MODE_ERROR,
    NEGATIVE_LIMIT_SWITCH,
    POSITIVE_LIMIT_SWITCH,
    SOFTWARE_LIMIT,
)
from cdcr_ctl.sim.epos.objects import AT_REST_COUNTS_S

#: Homing with a current threshold: the current must stay above it this long (s).
HOMING_CURRENT_DWELL_S = 0.002


class _Stepping:
    """Time stepping and supervision of :class:`~cdcr_ctl.sim.epos.node.SimEpos`."""

    # ================================================================== time
    def step(self, dt_s: float) -> None:
        """Advance the drive (set-point generators, supervision, motor) by ``dt_s`` seconds."""
        with self._lock:
            p = self.motor.p
            n = max(1, math.ceil(dt_s / p.substep_s - 1e-9))
            h = dt_s / n
            self._step_period_s = self.interpolation_period_s  # objects change between steps
            done = self._csp_substeps(h, n) if self.mode == Mode.CYCLIC_SYNC_POSITION else 0
            for _ in range(n - done):
                self._substep(h)

    def _csp_substeps(self, h: float, n: int) -> int:
        """Up to ``n`` sub-steps of :meth:`_substep` in its most common case (operation enabled,
        cyclic synchronous position, not halted, no supervision limit near), with the objects it
        reads looked up once per step instead of once per sub-step (the lock is held: nothing
        writes them meanwhile). The same arithmetic in the same order as :meth:`_substep` and
        :meth:`_supervise`; a sub-step outside that case goes through :meth:`_supervise`, and
        the first sub-step whose state or mode changed ends the fast path. Returns the sub-steps
        done (the caller does the rest with :meth:`_substep`)."""
        if self.state is not State.OPERATION_ENABLED or self._controlword_halted():
            return 0
        prof, motor, load_fn = self.profile, self.motor, self.load_fn
        period = self._step_period_s
        window = self._value(epos.FOLLOWING_ERROR_WINDOW)
        unbounded = window == 0xFFFFFFFF
        lo, hi = self._limits()
        lo1, hi1 = lo - 1, hi + 1
        offset = self.offset
        switches = motor.p.limit_switches_counts
        sw_lo, sw_hi = switches if switches is not None else (-math.inf, math.inf)
        tau = self.load_torque_Nm
        done = 0
        while done < n:
            if load_fn is not None:
                tau = load_fn(motor.x + offset, motor.v)
            motor.substep(h, prof.x, prof.v, prof.a, True, tau)
            self._csp_t = min(self._csp_t + h, period)
            v = (self._csp_to - self._csp_from) / period
            prof.a = 0.0
            prof.x, prof.v = self._csp_from + v * self._csp_t, (v if self._csp_t < period else 0.0)
            done += 1
            err = abs(prof.x - motor.x)
            actual = motor.x + offset
            if (unbounded or err <= window) and lo1 <= actual <= hi1 and sw_lo < motor.x < sw_hi:
                if err > self.max_following_error_counts:
                    self.max_following_error_counts = err
                self.following_error = False
                self._ferr_s = 0.0
            else:
                self._supervise(h)
                if self.state is not State.OPERATION_ENABLED:
                    break
        return done

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
