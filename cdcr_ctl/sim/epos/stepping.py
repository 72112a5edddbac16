"""The simulated EPOS in time: the axis advanced in sub-steps (set-point generators of each mode,
quick stop and halt ramps, homing against a hard stop, the motor of :mod:`.plant`), the
supervision on every sub-step (following error, software limits, limit switches) and the
heartbeat consumer of the master (0x1016).

A mixin of :class:`~cdcr_ctl.sim.epos.node.SimEpos` (the state lives on the node).
"""

from __future__ import annotations

import math

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import CW_HALT_BIT, Mode, State
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

# Module globals: read faster than the enums' attributes.
_OPERATION_ENABLED = State.OPERATION_ENABLED
_CSP = Mode.CYCLIC_SYNC_POSITION


def safe_box(lo1: int, hi1: int, offset: float, sw_lo: float, sw_hi: float) -> tuple[float, float]:
    """Raw positions (counts) ``(xmin, xmax)`` strictly inside which a sub-step meets
    :meth:`_Stepping._supervise`'s position checks ``lo1 <= x + offset <= hi1`` and
    ``sw_lo < x < sw_hi`` for certain: 1 count of margin against the rounding of ``lo1 -
    offset`` and ``hi1 - offset`` (below 2**-12 counts while ``|offset|`` < 2**40; rounding to
    nearest is monotonic and the integer bounds are floats exactly, so ``x + offset`` rounds
    inside them too). Empty (``(inf, -inf)``) when the offset is not that small: every
    sub-step then takes the exact comparisons."""
    if not abs(offset) < 2.0**40:
        return math.inf, -math.inf
    return max(lo1 - offset + 1.0, sw_lo), min(hi1 - offset - 1.0, sw_hi)


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
            done = self._csp_substeps(h, n) if self.mode == _CSP else 0
            for _ in range(n - done):
                self._substep(h)

    def _csp_substeps(self, h: float, n: int) -> int:
        """Up to ``n`` sub-steps of :meth:`_substep` in cyclic synchronous position (operation
        enabled, not halted; else none): the motor and the interpolated reference by
        :meth:`~cdcr_ctl.sim.epos.plant.Motor.substeps` with the objects :meth:`_supervise`
        reads looked up once per step (the lock is held: nothing writes them meanwhile). A
        sub-step inside :func:`safe_box` with an error below the largest so far (and the
        window) needs no supervision but the flags' reset; the first outside it goes through
        :meth:`_supervise`, and the first whose state changed ends the step. Returns the
        sub-steps done (the caller does the rest with :meth:`_substep`)."""
        if self._state is not _OPERATION_ENABLED or self.controlword & CW_HALT_BIT:
            return 0  # (the second: _controlword_halted without the call)
        motor, prof, load_fn = self.motor, self.profile, self.load_fn
        bounds = self._csp_bounds()
        period, window, unbounded, lo1, hi1, offset = bounds
        switches = motor.p.limit_switches_counts
        sw_lo, sw_hi = switches if switches is not None else (-math.inf, math.inf)
        xmin, xmax = safe_box(lo1, hi1, offset, sw_lo, sw_hi)
        wlim = math.inf if unbounded else float(window)
        tau = self.load_torque_Nm
        done = 0
        while done < n:
            vel = (self._csp_to - self._csp_from) / period
            if load_fn is not None:  # the torque from the state: one sub-step at a time
                tau = load_fn(motor.x + offset, motor.v)
            max_err = self.max_following_error_counts
            m = max_err if max_err <= wlim else wlim  # NaN: the window (and _supervise)
            j, prof.x, prof.v, prof.a, self._csp_t, inside = motor.substeps(
                h,
                1 if load_fn is not None else n - done,
                prof.x,
                prof.v,
                prof.a,
                True,
                tau,
                (self._csp_from, vel, period, self._csp_t),
                (xmin, xmax, m),
            )
            done += j
            if j > 1 or inside:  # within every limit: what _supervise does there
                self.following_error = False
                self._ferr_s = 0.0
            if not inside:
                self._supervise(h, bounds)
                if self._state is not _OPERATION_ENABLED:
                    break
        return done

    def _csp_bounds(self) -> tuple[float, float, bool, float, float, float]:
        """What :meth:`_supervise` checks against, looked up at once: ``(period, window,
        unbounded, lo - 1, hi + 1, offset)`` (period s, the rest counts)."""
        window = self._value(epos.FOLLOWING_ERROR_WINDOW)
        lo, hi = self._limits()
        return (self._step_period_s, window, window == 0xFFFFFFFF, lo - 1, hi + 1, self.offset)

    def _rpm(self, index: int, sub: int = 0) -> float:
        """A velocity/acceleration object in rpm (or rpm/s) as counts/s (or counts/s²)."""
        return self._value(index, sub) * self.cpr / 60.0

    def _substep(self, h: float) -> None:
        """Motor from t to t + h on the reference of t; then the reference moves on to t + h
        (so the controller compares reference and position of the same instant)."""
        if self.mode == _CSP and self._csp_substeps(h, 1):
            return  # cyclic synchronous position, enabled, not halted
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

    def _supervise(self, h: float, bounds: tuple | None = None) -> None:
        """Following error, software limits and limit switches after a sub-step; ``bounds``:
        :meth:`_csp_bounds` when the caller looked them up already."""
        _, window, unbounded, lo1, hi1, offset = bounds or self._csp_bounds()
        err = abs(self.profile.x - self.motor.x)
        if self.mode == Mode.CYCLIC_SYNC_POSITION:
            self.max_following_error_counts = max(self.max_following_error_counts, err)
        searching = self.mode == Mode.HOMING and self._homing_phase == "search"
        if not unbounded and err > window and not searching:
            self.following_error = True
            self._ferr_s += h
            if self._ferr_s * 1000.0 >= self._option(epos.FOLLOWING_ERROR_TIMEOUT, 0):
                self._fault(FOLLOWING_ERROR)
                return
        else:
            self.following_error = False
            self._ferr_s = 0.0
        actual = self.motor.x + offset
        if not lo1 <= actual <= hi1 and self.mode != Mode.HOMING:
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
