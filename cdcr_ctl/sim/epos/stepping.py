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

#: :func:`csp_times` results kept (few: one per segment start, sub-step and period in use).
_CSP_TIMES: dict[tuple[float, float, float, int], tuple[tuple[int, float], ...]] = {}
_CSP_TIMES_KEPT = 64


def csp_times(t0: float, h: float, period: float, n: int) -> tuple[tuple[int, float], ...]:
    """(sub-step number 1..n, segment time s after it) for ``n`` CSP sub-steps of ``h`` s from
    segment time ``t0`` s: :meth:`_Stepping._substep`'s ``min(t + h, period)`` repeated, the
    same additions in the same order (so the same floats), made once per (t0, h, period, n)."""
    key = (t0, h, period, n)
    out = _CSP_TIMES.get(key)
    if out is None:
        steps, t = [], t0
        for j in range(1, n + 1):
            t += h
            if period < t:
                t = period
            steps.append((j, t))
        out = tuple(steps)
        if len(_CSP_TIMES) >= _CSP_TIMES_KEPT:
            _CSP_TIMES.clear()
        _CSP_TIMES[key] = out
    return out


def safe_box(lo1: int, hi1: int, offset: float, sw_lo: float, sw_hi: float) -> tuple[float, float]:
    """Raw positions (counts) ``(xmin, xmax)`` strictly inside which a sub-step meets the CSP
    fast paths' position checks ``lo1 <= x + offset <= hi1`` and ``sw_lo < x < sw_hi`` for
    certain: 1 count of margin against the rounding of ``lo1 - offset`` and ``hi1 - offset``
    (below 2**-12 counts while ``|offset|`` < 2**40; rounding to nearest is monotonic and the
    integer bounds are floats exactly, so ``x + offset`` rounds inside them too). Empty
    (``(inf, -inf)``) when the offset is not that small: every sub-step then takes the exact
    comparisons."""
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
            fast = self.mode == _CSP and self.fast_paths
            done = self._csp_substeps(h, n) if fast else 0
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
        if self._state is not _OPERATION_ENABLED or self.controlword & CW_HALT_BIT:
            return 0  # (the second: _controlword_halted without the call)
        motor = self.motor
        if self.load_fn is None and motor.p.hard_stops_counts is None:
            return self._csp_substeps_inline(h, n)
        prof, load_fn = self.profile, self.load_fn
        period, window, unbounded, lo1, hi1, offset, sw_lo, sw_hi = self._csp_bounds()
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

    def _csp_substeps_inline(self, h: float, n: int) -> int:
        """:meth:`_csp_substeps` with a constant load torque and no hard stops (the lock-step
        rig's case): :meth:`~cdcr_ctl.sim.epos.plant.Motor.substep` (powered) written out with
        the axis state, the parameters and the reference in local variables: the same
        operations in the same order, so the same floats; performance only. The reference's
        times within the segment come from :func:`csp_times` (the same additions, made once);
        a sub-step is checked first against :func:`safe_box` (sufficient for the limits) and
        only outside it with :meth:`_supervise`'s exact comparisons. The state goes back to the
        objects before a sub-step that needs :meth:`_supervise` and at the end."""
        motor, prof = self.motor, self.profile
        p = motor.p
        k, kp, kd, ki = motor.k, motor._kp, motor._kd, motor._ki
        J, kt, ilim = p.inertia_kgm2, p.torque_constant_Nm_A, p.current_limit_A
        nilim = -ilim
        Jk = J * k  # Motor.substep's ``p.inertia_kgm2 * self.k * a_cmd`` groups left first
        visc = p.viscous_Nm_s_rad
        tau_gear = self.load_torque_Nm / p.gear_ratio
        copysign = math.copysign
        period, window, unbounded, lo1, hi1, offset, sw_lo, sw_hi = self._csp_bounds()
        xmin, xmax = safe_box(lo1, hi1, offset, sw_lo, sw_hi)
        wlim = math.inf if unbounded else float(window)
        x, v, integral, i = motor.x, motor.v, motor._integral, motor.i
        px, pv, pa = prof.x, prof.v, prof.a
        c_from, c_to = self._csp_from, self._csp_to
        max_err = self.max_following_error_counts
        # |px - x| <= m implies: within the window and no new maximum (m = min(max_err, wlim);
        # NaN compares False and takes the exact path).
        m = max_err if max_err <= wlim else wlim
        nm = -m
        # The segment's velocity: the same float every sub-step (from, to and period change
        # only in _supervise, after which it is computed again).
        vel = (c_to - c_from) / period
        supervised = 0  # the last sub-step that went through _supervise (0: none)
        done, t = 0, self._csp_t
        d = px - x  # Motor.substep's e = x_ref - x (from here on the last sub-step's d)
        for done, t in csp_times(self._csp_t, h, period, n):
            # Motor.substep (powered): a_cmd = pa + kp e + kd ev + ki integral, i = J k a_cmd / kt
            i = Jk * (pa + kp * d + kd * (pv - v) + ki * integral) / kt
            if i >= ilim or i <= nilim:  # abs(i) >= ilim without the call
                i = copysign(ilim, i)
            else:
                integral += d * h
            # torque = kt i + tau / N - b k v; v += torque / J / k * h (the same groupings)
            v += (kt * i + tau_gear - visc * (k * v)) / J / k * h
            x += v * h
            # the CSP reference moves on to t + h
            pa = 0.0
            px = c_from + vel * t
            pv = vel if t < period else 0.0
            d = px - x
            if d <= m and d >= nm and x < xmax and x > xmin:
                continue  # within every limit, max_err unchanged (sufficient: safe_box, m)
            err = -d if d < 0.0 else d  # abs(px - x) (NaN stays NaN)
            actual = x + offset
            if (unbounded or err <= window) and lo1 <= actual <= hi1 and sw_lo < x < sw_hi:
                if err > max_err:
                    max_err = err
                    m = max_err if max_err <= wlim else wlim
                    nm = -m
                continue
            self._write_back(x, v, integral, i, px, pv, pa, t, max_err, done - 1 > supervised)
            supervised = done
            self._supervise(h)
            x, v, integral, i = motor.x, motor.v, motor._integral, motor.i
            px, pv, pa = prof.x, prof.v, prof.a
            c_from, c_to = self._csp_from, self._csp_to
            vel = (c_to - c_from) / period
            max_err = self.max_following_error_counts
            m = max_err if max_err <= wlim else wlim
            nm = -m
            d = px - x
            if self._state is not _OPERATION_ENABLED:
                return done
        self._write_back(x, v, integral, i, px, pv, pa, t, max_err, done > supervised)
        return done

    def _csp_bounds(self) -> tuple[float, float, bool, float, float, float, float, float]:
        """What the CSP fast paths check each sub-step against, looked up once per step:
        ``(period, window, unbounded, lo - 1, hi + 1, offset, switch_lo, switch_hi)``."""
        window = self._value(epos.FOLLOWING_ERROR_WINDOW)
        lo, hi = self._limits()
        switches = self.motor.p.limit_switches_counts
        sw_lo, sw_hi = switches if switches is not None else (-math.inf, math.inf)
        return (
            self._step_period_s,
            window,
            window == 0xFFFFFFFF,
            lo - 1,
            hi + 1,
            self.offset,
            sw_lo,
            sw_hi,
        )

    def _write_back(
        self,
        x: float,
        v: float,
        integral: float,
        i: float,
        px: float,
        pv: float,
        pa: float,
        csp_t: float,
        max_err: float,
        clear: bool,
    ) -> None:
        """:meth:`_csp_substeps_inline`'s local state back to the motor, the profile and this
        node (before a sub-step that needs :meth:`_supervise`, and at the end); ``clear``: a
        sub-step within every limit since the last write-back."""
        motor, prof = self.motor, self.profile
        motor.x, motor.v, motor._integral, motor.i = x, v, integral, i
        prof.x, prof.v, prof.a = px, pv, pa
        self._csp_t = csp_t
        self.max_following_error_counts = max_err
        if clear:
            self.following_error = False
            self._ferr_s = 0.0

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
