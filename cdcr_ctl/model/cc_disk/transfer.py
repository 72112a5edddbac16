"""Fast force-transfer chain for one pose (plain floats): the hot path of compensation and forward.

Composes, for S segments and K cables, the equations implemented for reference (numpy) in
:mod:`~cdcr_ctl.model.cc_disk.kinematics`, :mod:`~cdcr_ctl.model.cc_disk.routing`,
:mod:`~cdcr_ctl.model.cc_disk.statics`, :mod:`~cdcr_ctl.model.shared.friction`,
:mod:`~cdcr_ctl.model.shared.capstan` and :mod:`~cdcr_ctl.model.cc_disk.elongation` (the tests check
every quantity against those):

    bending vectors x -> q_geom (eq. 4 / chords) -> wrap angles (eq. 21-22, closed forms)
    -> mean span-tension factors (eq. 23) -> moment demand (eq. 8 + disk weights)
    -> anchor tensions (eq. 9-15, pretension rule) -> base tensions (eq. 23)
    -> pulley tensions (eq. 29-32 tables) -> delta_in, delta_out (eq. 33-36) -> q = q_geom + delta

Everything numpy could vectorise is 3x3-sized, where numpy's per-call overhead dominates, so the
chain runs on Python floats with all constants precomputed at construction. This module holds
the pose half (geometry, wrap angles, moment demand); the tension half is the mixin
:class:`~cdcr_ctl.model.cc_disk.tension_chain.TensionChain`.

Units: mm, N, rad. ``xs`` is the flat list of bending vectors (x_1, y_1, x_2, y_2, ...) with
x_i = theta_i (cos phi_i, sin phi_i); ``s`` the mobilised friction fractions per cable.
"""

from __future__ import annotations

import math

from cdcr_ctl.model.cc_disk.kinematics import SERIES_BELOW, c2, d1, d2, e2, s1
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams, cable_radius_mm, is_rigid
from cdcr_ctl.model.cc_disk.routing import tangent_angle
from cdcr_ctl.model.cc_disk.statics import G_MM_S2_TO_N, tip_load_force, xs_to_psi
from cdcr_ctl.model.cc_disk.tension_chain import Pose, TensionChain, Transfer, _min_sum_pair
from cdcr_ctl.model.shared.capstan import PulleyTransfer

__all__ = ["ForceTransfer", "Pose", "TensionChain", "Transfer", "_min_sum_pair"]


class ForceTransfer(TensionChain):
    """The force-transfer chain of one robot with one set of effects (precomputed constants)."""

    def __init__(self, params: RobotParams, effects: Effects | None = None) -> None:
        eff = Effects() if effects is None else effects
        self.params = params
        self.effects = eff
        S, K = params.n_segments, params.n_cables
        self.S, self.K = S, K
        segs = params.segments
        self._l = [s.length_mm for s in segs]
        self._n = [s.n_disks for s in segs]
        self._kEI = [s.EI_Nmm2 / s.length_mm for s in segs]
        self._thick = [s.disk_thickness_mm > 0.0 for s in segs]
        self._tk = [s.disk_thickness_mm for s in segs]
        self._inner_frac = [(s.n_disks - 1) / s.n_disks for s in segs]
        self._half0 = 0.5 / segs[0].n_disks
        disk_weights = eff.gravity and any(s.disk_mass_g > 0 for s in segs)
        # a payload at the tip weighs whatever the disk-weight switch says: it is a load the
        # config names, a point mass at arc fraction 1 of the last segment
        self._gravity = disk_weights or params.tip_mass_g > 0.0
        g = params.gravity_mm_s2
        self._g = (g[0] * G_MM_S2_TO_N, g[1] * G_MM_S2_TO_N, g[2] * G_MM_S2_TO_N)
        self._disks = [
            [(m / s.n_disks, s.disk_mass_g) for m in range(1, s.n_disks + 1)]
            if s.disk_mass_g > 0 and disk_weights
            else []
            for s in segs
        ]
        if params.tip_mass_g > 0.0:
            self._disks[-1].append((1.0, params.tip_mass_g))
        #: tip force (N, base frame), None when there is none (see :meth:`_tip_force_demand`)
        self._tip_F = tuple(params.tip_force_N) if params.has_tip_force else None
        self._disk_mass = [sum(m for _, m in d) for d in self._disks]
        #: per disk (sig, m sig^2, m sig^3, m sig^4, m sig): the weights' pose-free factors, each
        #: the product _moment_demand formed left to right (the same floats)
        self._disk_w = [
            [(sig, m * sig * sig, m * sig * sig * sig, m * sig * sig * sig * sig, m * sig)
             for sig, m in d]
            for d in self._disks
        ]  # fmt: skip
        cab = params.cables
        self._a = [c.segment for c in cab]
        self._r = [c.routing_radius_mm for c in cab]
        self._gam = [c.hole_angle_rad for c in cab]
        self._ex = [c.routing_radius_mm * math.cos(c.hole_angle_rad) for c in cab]
        self._ey = [c.routing_radius_mm * math.sin(c.hole_angle_rad) for c in cab]
        self._T0 = [c.pretension_N for c in cab]
        self._rigid = [is_rigid(c, eff) for c in cab]
        self._iEA = [0.0 if self._rigid[k] else 1.0 / c.EA_N for k, c in enumerate(cab)]
        self._mu = [c.mu_disk if eff.disk_friction else 0.0 for c in cab]
        self._pul: list[list[PulleyTransfer]] = []
        for c in cab:
            trs = []
            for p in c.pulleys:
                alpha = p.alpha if eff.pulley_friction else 0.0
                trs.append(
                    PulleyTransfer(
                        p.radius_mm,
                        p.wrap_angle_rad,
                        alpha,
                        p.n,
                        cable_radius_mm(c),
                        eff.capstan_points,
                    )
                )
            self._pul.append(trs)
        self._pul_rev = [list(reversed(t)) for t in self._pul]
        #: ln kappa of each pulley of each cable at its pretension (friction capacity)
        self._pul_lnk0 = [[tr.ln_kappa(self._T0[k]) for tr in t] for k, t in enumerate(self._pul)]
        self._run = [c.free_length_mm / (len(c.pulleys) + 1) for c in cab]
        self._own = [list(params.cables_of(i)) for i in range(S)]
        self._distal = [[k for k in range(K) if self._a[k] > i] for i in range(S)]
        self._crossing = [[k for k in range(K) if self._a[k] >= i] for i in range(S)]
        self._has_friction = [
            self._mu[k] > 0.0 or any(not t.frictionless for t in self._pul[k]) for k in range(K)
        ]
        self._chord = eff.geometry == "chord"
        self._last_xs: list[float] | None = None
        self._last_pose: Pose | None = None
        self._cc_arm = [(self._ex[k], self._ey[k]) for k in range(K)]
        #: segments some cable crosses (the chord geometry's per-segment factors)
        self._n_arm_segs = max(self._a) + 1 if K else 0
        #: per segment (n, l, t, 2 n t, 2 n, 4 n^2, 4 n): the chord factors' pose-free parts
        self._chord_k = [
            (s.n_disks, s.length_mm, s.disk_thickness_mm, 2.0 * s.n_disks * s.disk_thickness_mm,
             2.0 * s.n_disks, 4.0 * s.n_disks * s.n_disks, 4.0 * s.n_disks)
            for s in segs
        ]  # fmt: skip

    # ------------------------------------------------------------------ geometry and loads
    def pose(self, xs: list[float]) -> Pose:
        """Geometry, wrap angles and moment demand at bending vectors ``xs`` (flat, rad).

        The last pose is kept: the loop asks for the same pose for the ideal displacements, the
        compensation and the tip in one cycle (a Pose is not mutated by its users).
        """
        if xs == self._last_xs:
            return self._last_pose
        pose = self._pose(xs)
        self._last_xs, self._last_pose = list(xs), pose
        return pose

    def _pose(self, xs: list[float]) -> Pose:
        S, K = self.S, self.K
        theta = [0.0] * S
        ux = [1.0] * S
        uy = [0.0] * S
        for i in range(S):
            X, Y = xs[2 * i], xs[2 * i + 1]
            t = math.sqrt(X * X + Y * Y)
            theta[i] = t
            if t > 0.0:
                ux[i] = X / t
                uy[i] = Y / t
        # wrap angles (routing.py closed forms): base hole, inner holes, boundary disks
        inner = [theta[i] / self._n[i] for i in range(S)]
        Zb = [0.0] * S
        z = theta[0] * self._half0
        for i in range(S):
            if i > 0:
                A = 0.5 * inner[i - 1]
                B = 0.5 * inner[i]
                if self._thick[i - 1]:
                    z += A + B
                else:
                    z += tangent_angle(A, ux[i - 1], uy[i - 1], B, ux[i], uy[i])
            z += theta[i] * self._inner_frac[i]
            Zb[i] = z
        # cable shortening and moment arms
        if not self._chord:
            sx = sy = 0.0
            pre = []
            for i in range(S):
                sx += xs[2 * i]
                sy += xs[2 * i + 1]
                pre.append((sx, sy))
            q_geom = [
                self._ex[k] * pre[self._a[k]][0] + self._ey[k] * pre[self._a[k]][1]
                for k in range(K)
            ]
            arm = [[self._cc_arm[k]] * (self._a[k] + 1) for k in range(K)]
        else:
            q_geom, arm = self._chord_geometry(xs, theta, ux, uy)
        m_req = self._moment_demand(xs, theta)
        if self._tip_F is not None:
            m_req = self._tip_force_demand(xs, m_req)
        return Pose(theta, q_geom, arm, Zb, inner, m_req)

    def _tip_force_demand(
        self, xs: list[float], m_req: list[tuple[float, float]]
    ) -> list[tuple[float, float]]:
        """m_i - Q_F,i: the generalised force Q_F = J_tip^T F of the tip force (bending-vector
        coordinates, :func:`cdcr_ctl.statics.tip_load_force`), N*mm."""
        Q = tip_load_force(xs_to_psi(xs), self.params, "x", weight=False)
        return [(m_req[i][0] - Q[2 * i], m_req[i][1] - Q[2 * i + 1]) for i in range(self.S)]

    def _chord_geometry(self, xs, theta, ux, uy):
        """q_geom and arms with the exact chords (routing.segment_chord_shortening and its
        gradient), the per-segment factors computed once for all the cables crossing it.

        Per segment, a = theta/2n: shortening l (1 - s1(a)) + 2 n r cos(phi - gamma) sin a
        - 2 n t sin^2(a/2), with r cos(phi - gamma) = e.u (e = r (cos gamma, sin gamma) the hole,
        u = (cos phi, sin phi)); gradient w.r.t. x_i: f x_i + s1(a) e with
        f = d1(a)/4n^2 (e.x_i - l) - t s1(a)/4n, since ds1(a)/dx = d1(a) x/4n^2.
        """
        seg = []
        for i in range(self._n_arm_segs):
            n, L, tk, two_n_tk, two_n, four_n2, four_n = self._chord_k[i]
            a = 0.5 * theta[i] / n
            sn = math.sin(a)
            sa = s1(a)
            da = d1(a)
            h = math.sin(0.5 * a)
            seg.append(
                (L * (1.0 - sa) - two_n_tk * h * h, two_n * sn, da / four_n2, tk * sa / four_n, sa)
            )
        ls = self._l
        q_geom, arm = [], []
        for k in range(self.K):
            ex, ey = self._ex[k], self._ey[k]
            qk = 0.0
            ak = []
            for i in range(self._a[k] + 1):
                X, Y = xs[2 * i], xs[2 * i + 1]
                base, two_n_sin, fd, ft, sa = seg[i]
                qk += base + two_n_sin * (ex * ux[i] + ey * uy[i])
                f = fd * (ex * X + ey * Y - ls[i]) - ft
                ak.append((f * X + sa * ex, f * Y + sa * ey))
            q_geom.append(qk)
            arm.append(ak)
        return q_geom, arm

    def _moment_demand(self, xs: list[float], theta: list[float]) -> list[tuple[float, float]]:
        """m_i = (EI/l) x_i - Q_x,i; the weights by two passes over the chain (see statics.py)."""
        S = self.S
        if not self._gravity:
            return [(self._kEI[i] * xs[2 * i], self._kEI[i] * xs[2 * i + 1]) for i in range(S)]
        # pass 1, base -> tip: local rotations, tip positions, gravity (per gram) per base frame
        gx, gy, gz = self._g
        Rs, ps, gs, rat = [], [], [], []
        # (one segment: pass 2 uses only its gravity, the rest of pass 1 would be dead)
        for i in range(S if S > 1 else 0):
            X, Y, t, L = xs[2 * i], xs[2 * i + 1], theta[i], self._l[i]
            a, b = s1(t), c2(t)
            R = (
                1.0 - b * X * X, -b * X * Y, a * X,
                -b * X * Y, 1.0 - b * Y * Y, a * Y,
                -a * X, -a * Y, 1.0 - b * t * t,
            )  # fmt: skip
            Rs.append(R)
            ps.append((L * b * X, L * b * Y, L * a))
            gs.append((gx, gy, gz))
            rat.append((b, d1(t), d2(t), e2(t)))
            gx, gy, gz = (
                R[0] * gx + R[3] * gy + R[6] * gz,
                R[1] * gx + R[4] * gy + R[7] * gz,
                R[2] * gx + R[5] * gy + R[8] * gz,
            )
        if S == 1:
            gs.append((gx, gy, gz))
        # pass 2, tip -> base: own disks, then everything distal as one mass and first moment
        out: list[tuple[float, float]] = [(0.0, 0.0)] * S
        Ex = Ey = Ez = 0.0  # sum m (x_m - P_i) of the distal disks, in segment i's tip frame
        Md = 0.0
        for i in range(S - 1, -1, -1):
            X, Y, t, L = xs[2 * i], xs[2 * i + 1], theta[i], self._l[i]
            gx, gy, gz = gs[i]
            # own disks (mass m at arc fraction sig): first moment m (sig^2 l c2 X, sig^2 l c2 Y,
            # sig l s1) and weight moment m sig^2 l (c2 g + sig^2 d2 x (x.g) + sig d1 x g_z),
            # ratios at sig theta, summed over the disks as four scalars (A, B, C, D) first
            A, B, C, D = _disk_sums(self._disk_w[i], t)
            om = self._disk_mass[i]
            xg = X * gx + Y * gy
            Qx = L * (A * gx + (B * xg + C * gz) * X)
            Qy = L * (A * gy + (B * xg + C * gz) * Y)
            if i == 0 and Md == 0.0:  # one segment: nothing distal, nothing below
                out[0] = (self._kEI[0] * X - Qx, self._kEI[0] * Y - Qy)
                break
            R = Rs[i]
            Dx = R[0] * Ex + R[1] * Ey + R[2] * Ez
            Dy = R[3] * Ex + R[4] * Ey + R[5] * Ez
            Dz = R[6] * Ex + R[7] * Ey + R[8] * Ez
            if Md > 0.0:
                cc2, dd1, dd2, ee2 = rat[i]
                Fx, Fy, Fz = Md * gx, Md * gy, Md * gz
                xF = X * Fx + Y * Fy
                Qx += L * (cc2 * Fx + dd2 * X * xF + dd1 * X * Fz)
                Qy += L * (cc2 * Fy + dd2 * Y * xF + dd1 * Y * Fz)
                tx = Dy * gz - Dz * gy
                ty = Dz * gx - Dx * gz
                tz = Dx * gy - Dy * gx
                k_ = ee2 * (X * tx + Y * ty) + cc2 * tz
                Qx += ty - Y * k_
                Qy += -tx + X * k_
            out[i] = (self._kEI[i] * X - Qx, self._kEI[i] * Y - Qy)
            if i == 0:
                break  # the distal sums are for the next segment down
            p = ps[i]
            ox = L * A * X
            oy = L * A * Y
            oz = L * D
            Ex = ox + Md * p[0] + Dx
            Ey = oy + Md * p[1] + Dy
            Ez = oz + Md * p[2] + Dz
            Md += om
        return out


def _disk_sums(disks: list[tuple[float, ...]], t: float) -> tuple[float, float, float, float]:
    """(A, B, C, D) = sums over a segment's disks of m sig^2 c2, m sig^4 d2, m sig^3 d1 and
    m sig s1, the ratios at sig t (rad), t the segment's bend; ``disks`` the pose-free factors
    (sig, m sig^2, m sig^3, m sig^4, m sig) of :attr:`ForceTransfer._disk_w`. The ratios
    :func:`~cdcr_ctl.model.cc_disk.kinematics.s1`, ``c2``, ``d1`` and ``d2`` written out per disk
    from one sine and one cosine (it runs for every disk of every pose; measured by
    ``benchmarks/bench_hot_paths.py``, held to the kinematics ratios by a test)."""
    A = B = C = D = 0.0
    for sig, ms2, ms3, ms4, ms in disks:
        st = sig * t
        if abs(st) < SERIES_BELOW:
            t2 = st * st
            t4 = t2 * t2
            t6 = t4 * t2
            ss1 = 1.0 - t2 / 6.0 + t4 / 120.0 - t6 / 5040.0 + t4 * t4 / 362880.0
            cc2 = 0.5 - t2 / 24.0 + t4 / 720.0 - t6 / 40320.0 + t4 * t4 / 3628800.0
            dd1 = -1.0 / 3.0 + t2 / 30.0 - t4 / 840.0 + t6 / 45360.0
            dd2 = -1.0 / 12.0 + t2 / 180.0 - t4 / 6720.0 + t6 / 453600.0
        else:
            sn = math.sin(st)
            h = math.sin(0.5 * st)
            omc = 2.0 * h * h
            it = 1.0 / st
            it2 = it * it
            ss1 = sn * it
            cc2 = omc * it2
            dd1 = (st * math.cos(st) - sn) * it2 * it
            dd2 = (st * sn - 2.0 * omc) * it2 * it2
        A += ms2 * cc2
        B += ms4 * dd2
        C += ms3 * dd1
        D += ms * ss1
    return A, B, C, D
