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
        ``a_ff`` (counts/s²), with ``tau_ext_Nm`` at the gearbox output."""
        p = self.p
        if powered:
            e, ev = x_ref - self.x, v_ref - self.v
            a_cmd = a_ff + self._kp * e + self._kd * ev + self._ki * self._integral
            i = p.inertia_kgm2 * self.k * a_cmd / p.torque_constant_Nm_A
            if abs(i) >= p.current_limit_A:
                i = math.copysign(p.current_limit_A, i)
            else:
                self._integral += e * h
            self.i = i
        else:
            self.i = 0.0
            self._integral = 0.0
        omega = self.k * self.v
        torque = p.torque_constant_Nm_A * self.i + tau_ext_Nm / p.gear_ratio
        torque -= p.viscous_Nm_s_rad * omega
        if p.hard_stops_counts is not None:
            lo, hi = p.hard_stops_counts
            if self.x > hi:
                torque -= (
                    p.stop_stiffness_Nm_rad * self.k * (self.x - hi) + self._stop_damping * omega
                )
            elif self.x < lo:
                torque -= (
                    p.stop_stiffness_Nm_rad * self.k * (self.x - lo) + self._stop_damping * omega
                )
        self.v += torque / p.inertia_kgm2 / self.k * h
        self.x += self.v * h

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
