"""The simulated drive's physics: a DC motor with encoder and gearbox under a position controller,
and the set-point generators of the EPOS modes. Deterministic: time only moves in
:meth:`Motor.substep` calls, never by a wall clock.

Everything is in the motor's encoder counts (``x`` counts, ``v`` counts/s, ``a`` counts/s²);
``k = 2π / counts_per_rev`` converts counts to motor radians. Motor-shaft dynamics
(semi-implicit Euler, step ``h`` s):

    J dω/dt = kt·i + τ_ext / N + τ_stop − b·ω,       ω = k·v,

with ``i`` the current the position controller asks for, clamped to ±``current_limit_A``, ``τ_ext``
the external torque at the gearbox output (N·m; + acts in the + count direction, e.g. cable
tension × spool radius with a sign), ``N`` the gear ratio (motor turns per output turn), ``τ_stop``
a stiff spring-damper beyond the mechanical hard stops (if any) and ``b`` viscous friction.

Position controller (EPOS PID with feed-forward, tuned as a triple pole at ``ω_c = 2π·bandwidth_hz``
on the rigid inertia): ``a_cmd = a_ff + 3ω_c²·e + 3ω_c·ė + ω_c³·∫e``, ``i = J·k·a_cmd / kt``; the
integral stops while the current saturates (anti-windup). With the power stage off, ``i = 0`` and
the motor coasts.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class MotorParams:
    """Motor, encoder, gearbox and controller of one simulated axis (SI units, counts).

    Defaults: a maxon A-max 22 class motor (kt 10.6 mN·m/A, rotor plus reflected load 6e-7 kg·m²)
    with a 512-line encoder (2048 quadrature counts per turn) and a 19:1 gearbox.
    """

    counts_per_rev: int = 2048
    gear_ratio: float = 19.0
    inertia_kgm2: float = 6e-7
    torque_constant_Nm_A: float = 0.0106
    current_limit_A: float = 2.0
    viscous_Nm_s_rad: float = 2e-6
    bandwidth_hz: float = 40.0
    substep_s: float = 0.00025
    #: Mechanical hard stops in raw encoder counts (min, max), or None for none.
    hard_stops_counts: tuple[float, float] | None = None
    stop_stiffness_Nm_rad: float = 5.0
    #: Limit switches in raw encoder counts (negative, positive), or None for none.
    limit_switches_counts: tuple[float, float] | None = None


class Motor:
    """State and one integration step of the axis (see the module docstring)."""

    def __init__(self, p: MotorParams) -> None:
        self.p = p
        self.k = 2 * math.pi / p.counts_per_rev
        self.x = 0.0  # raw encoder counts
        self.v = 0.0  # counts/s
        self.i = 0.0  # A
        self._integral = 0.0
        w = 2 * math.pi * p.bandwidth_hz
        self._kp, self._kd, self._ki = 3 * w * w, 3 * w, w**3
        self._stop_damping = 2 * 0.5 * math.sqrt(p.stop_stiffness_Nm_rad * p.inertia_kgm2)

    def substep(
        self, h: float, x_ref: float, v_ref: float, a_ff: float, powered: bool, tau_ext_Nm: float
    ) -> None:
        """Advance ``h`` seconds towards reference ``x_ref`` (counts), ``v_ref`` (counts/s),
        ``a_ff`` (counts/s²), with ``tau_ext_Nm`` at the gearbox output: one of
        :meth:`substeps`."""
        self.substeps(h, 1, x_ref, v_ref, a_ff, powered, tau_ext_Nm)

    def substeps(
        self,
        h: float,
        n: int,
        x_ref: float,
        v_ref: float,
        a_ff: float,
        powered: bool,
        tau_ext_Nm: float,
        segment: tuple[float, float, float, float] | None = None,
        box: tuple[float, float, float] | None = None,
    ) -> tuple[int, float, float, float, float, bool]:
        """Up to ``n`` sub-steps of ``h`` s (the module docstring's equations, semi-implicit
        Euler), the state in local variables (Python floats) for speed.

        ``segment = (x_from, velocity, period, t)``: after each sub-step the reference moves
        on along a straight line (the CSP interpolation: segment time ``t = min(t + h,
        period)``, ``x_ref = x_from + velocity t``, ``v_ref = velocity`` until the period's
        end, then 0, ``a_ff = 0``); without it the reference stays. ``box = (xmin, xmax,
        m)``: stop after the first sub-step where the position leaves ``(xmin, xmax)`` or the
        error ``x_ref - x`` leaves ``[-m, m]`` (the caller supervises that one).

        Returns ``(sub-steps done, x_ref, v_ref, a_ff, t, every one inside the box)``."""
        p = self.p
        k, kp, kd, ki = self.k, self._kp, self._kd, self._ki
        J, kt, ilim = p.inertia_kgm2, p.torque_constant_Nm_A, p.current_limit_A
        nilim = -ilim
        Jk = J * k  # i = J k a_cmd / kt, grouped left first
        visc = p.viscous_Nm_s_rad
        tau_gear = tau_ext_Nm / p.gear_ratio
        stops = p.hard_stops_counts
        copysign = math.copysign
        x, v, integral, i = self.x, self.v, self._integral, self.i
        px, pv, pa = x_ref, v_ref, a_ff
        c_from, vel, period, t = segment if segment is not None else (0.0, 0.0, 0.0, 0.0)
        xmin, xmax, m = box if box is not None else (-math.inf, math.inf, math.inf)
        nm = -m
        inside = True
        done = 0
        while done < n:
            if powered:
                # a_cmd = a_ff + kp e + kd ev + ki integral; the integral stops while saturated
                d = px - x
                i = Jk * (pa + kp * d + kd * (pv - v) + ki * integral) / kt
                if i >= ilim or i <= nilim:  # abs(i) >= ilim without the call
                    i = copysign(ilim, i)
                else:
                    integral += d * h
            else:
                i = integral = 0.0
            omega = k * v
            torque = kt * i + tau_gear - visc * omega
            if stops is not None:
                lo, hi = stops
                if x > hi:
                    torque -= p.stop_stiffness_Nm_rad * k * (x - hi) + self._stop_damping * omega
                elif x < lo:
                    torque -= p.stop_stiffness_Nm_rad * k * (x - lo) + self._stop_damping * omega
            v += torque / J / k * h
            x += v * h
            done += 1
            if segment is not None:
                t += h
                if period < t:  # min(t + h, period)
                    t = period
                pa = 0.0
                px = c_from + vel * t
                pv = vel if t < period else 0.0
            if box is not None:
                d = px - x
                if not (d <= m and d >= nm and x < xmax and x > xmin):
                    inside = False
                    break
        self.x, self.v, self._integral, self.i = x, v, integral, i
        return done, px, pv, pa, t, inside

    def reset_controller(self) -> None:
        self._integral = 0.0


class Profile:
    """Set-point generator: trapezoidal moves, velocity ramps and stops (counts, counts/s)."""

    def __init__(self) -> None:
        self.x = 0.0
        self.v = 0.0
        self.a = 0.0

    def set(self, x: float, v: float = 0.0) -> None:
        self.x, self.v, self.a = x, v, 0.0

    def _advance(self, v_new: float, h: float) -> None:
        self.a = (v_new - self.v) / h
        self.x += 0.5 * (self.v + v_new) * h
        self.v = v_new

    def move(self, target: float, v_max: float, acc: float, dec: float, h: float) -> bool:
        """One step of a trapezoidal move to ``target``; True once there (at rest)."""
        d = target - self.x
        if abs(d) <= max(acc, dec) * h * h and abs(self.v) <= max(acc, dec) * h:
            self.set(target)
            return True
        direction = math.copysign(1.0, d)
        toward = self.v * direction
        stopping = toward * toward / (2 * dec) if toward > 0 else 0.0
        if toward < 0:
            v_new = self.v + direction * dec * h
        elif abs(d) <= stopping + toward * h:
            v_new = self.v - direction * min(dec * h, toward)
            if v_new * direction <= 0:
                v_new = direction * min(dec * h, math.sqrt(2 * dec * abs(d)))
        else:
            v_new = direction * min(toward + acc * h, v_max)
        self._advance(v_new, h)
        if (target - self.x) * direction < 0 and abs(self.v) <= dec * h * 2:
            self.set(target)
            return True
        return False

    def ramp_velocity(self, v_target: float, acc: float, h: float) -> None:
        """One step of a velocity ramp to ``v_target`` at ``acc``."""
        dv = v_target - self.v
        self._advance(self.v + math.copysign(min(abs(dv), acc * h), dv), h)

    def stop(self, dec: float, h: float) -> bool:
        """One step of a stop at deceleration ``dec``; True once at rest."""
        self.ramp_velocity(0.0, dec, h)
        return self.v == 0.0


class PvtBuffer:
    """EPOS2 interpolated position mode: PVT points consumed with cubic Hermite segments.

    A point is (position counts, velocity counts/s, time s from the previous point). Segment k runs
    from the previous point (or where the axis stood when interpolation began) to point k.
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.points: deque[tuple[float, float, float]] = deque()
        self.active = False
        self._p0 = 0.0
        self._v0 = 0.0
        self._t = 0.0

    def push(self, p: float, v: float, t_s: float) -> bool:
        """Queue a point; False when the buffer is full (overflow)."""
        if len(self.points) >= self.capacity:
            return False
        self.points.append((p, v, t_s))
        return True

    def clear(self) -> None:
        self.points.clear()
        self.active = False
        self._t = 0.0

    def start(self, p0: float, v0: float) -> None:
        self.active, self._p0, self._v0, self._t = True, p0, v0, 0.0

    def sample(self, h: float) -> tuple[float, float] | None:
        """Advance ``h`` s; (x, v) on the path, or None on underflow (no point left)."""
        self._t += h
        while self.points and self._t >= self.points[0][2]:
            p1, v1, t1 = self.points.popleft()
            self._t -= t1
            self._p0, self._v0 = p1, v1
        if not self.points:
            return None
        p1, v1, t1 = self.points[0]
        s = self._t / t1 if t1 > 0 else 1.0
        s2, s3 = s * s, s * s * s
        x = (
            (2 * s3 - 3 * s2 + 1) * self._p0
            + (s3 - 2 * s2 + s) * t1 * self._v0
            + (-2 * s3 + 3 * s2) * p1
            + (s3 - s2) * t1 * v1
        )
        v = (
            (
                (6 * s2 - 6 * s) * self._p0
                + (3 * s2 - 4 * s + 1) * t1 * self._v0
                + (-6 * s2 + 6 * s) * p1
                + (3 * s2 - 2 * s) * t1 * v1
            )
            / t1
            if t1 > 0
            else 0.0
        )
        return x, v

    @property
    def hold(self) -> tuple[float, float]:
        """The last point reached (where the axis rests after an underflow)."""
        return self._p0, self._v0
