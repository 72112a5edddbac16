"""The tension half of the force-transfer chain: friction factors, statics, along the cable.

:class:`TensionChain` is the mixin of :class:`~cdcr_ctl.model.cc_disk.transfer.ForceTransfer` that
turns a :class:`Pose` into tensions and cable displacements (Qi et al. 2023): mean span-tension
factors (eq. 23) -> anchor tensions (eq. 9-15, pretension rule) -> base tensions (eq. 23) ->
pulley tensions (eq. 29-32 tables) -> delta_in, delta_out (eq. 33-36) -> q = q_geom + delta.
Plain floats, constants precomputed by ``ForceTransfer.__init__``. Units: mm, N, rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.params import Location
from cdcr_ctl.model.shared.capstan import PulleyTransfer


@dataclass(slots=True)
class Pose:
    """Per-pose quantities shared by the inverse and the forward residual (internal, plain lists).

    ``q_seg[k][i]`` shortening of cable k in segment i (mm), ``arm[k][i]`` its gradient w.r.t.
    x_i (mm/rad, (2,) tuple), ``Zb[i]`` summed wrap (rad) from the base hole to the last span of
    segment i, ``inner[i]`` = theta_i/n_i, ``m_req[i]`` the moment demand (N*mm, (2,) tuple).
    """

    theta: list[float]
    q_geom: list[float]
    arm: list[list[tuple[float, float]]]
    Zb: list[float]
    inner: list[float]
    m_req: list[tuple[float, float]]


@dataclass(slots=True)
class Transfer:
    """Result of one evaluation of the chain (lists, cable order; N and mm)."""

    q_geom: list[float]
    T_distal: list[float]
    T_base: list[float]
    T_actuator: list[float]
    delta_in: list[float]
    delta_out: list[float]
    w: list[float]
    q: list[float]

    def T_at(self, k: int, location: Location) -> float:
        return self.T_base[k] if location == "robot_base" else self.T_actuator[k]


class TensionChain:
    """Friction factors, statics and the along-the-cable transfer of :class:`ForceTransfer`.

    Uses the constants ``ForceTransfer.__init__`` precomputes and its :meth:`pose`.
    """

    # ------------------------------------------------------------------ friction factors
    def factors(self, pose: Pose, s: list[float]) -> tuple[list[list[float]], list[float]]:
        """(Fbar[k][i], ln(T_base/T_distal)[k]) for mobilised fractions ``s`` (eq. 23)."""
        Fb, Eb = [], []
        for k in range(self.K):
            row, e = self.factors_k(pose, k, s[k])
            Fb.append(row)
            Eb.append(e)
        return Fb, Eb

    def factors_k(self, pose: Pose, k: int, s_k: float) -> tuple[list[float], float]:
        """Mean span-tension factors of cable k per crossed segment and its ln(T_base/T_distal).

        Spans of segment i (n_i of them) sit beyond Zb[a] - Zb[i] of wrap from the anchor plus
        p theta_i/n_i, p = 0..n_i-1, so their mean factor is
        exp(beta (Zb[a] - Zb[i])) * expm1(n beta theta/n) / (n expm1(beta theta/n)),
        beta = s mu (:func:`cdcr_ctl.model.shared.friction.mean_geometric`).
        """
        a = self._a[k]
        beta = s_k * self._mu[k]
        if beta == 0.0:
            return [1.0] * (a + 1), 0.0
        Zb, inner, n = pose.Zb, pose.inner, self._n
        za = Zb[a]
        row = []
        for i in range(a + 1):
            y = beta * inner[i]
            ni = n[i]
            G = 1.0 if y == 0.0 else math.expm1(ni * y) / (ni * math.expm1(y))
            row.append(math.exp(beta * (za - Zb[i])) * G)
        return row, beta * za

    # ------------------------------------------------------------------ statics
    def statics(self, pose: Pose, Fb: list[list[float]]) -> list[float]:
        """Anchor tensions (N): back-substitution tip -> base with the pretension rule.

        The rule acts on the mean tension of each cable along its anchor segment (what the
        moment balance sees); with friction the anchor tension is that over Fbar_k,a.
        """
        T = [0.0] * self.K
        coupling = self.effects.coupling
        gain = self.effects.coupling_gain
        arm = pose.arm
        for i in range(self.S - 1, -1, -1):
            bx, by = pose.m_req[i]
            if coupling:
                for k in self._distal[i]:
                    f = T[k] * Fb[k][i]
                    if gain != 1.0:
                        f *= gain
                    ax, ay = arm[k][i]
                    bx -= f * ax
                    by -= f * ay
            # own cables: unknown mean tension M_k = T_k Fbar_k,i along the anchor segment
            own = self._own[i]
            cols = []
            for k in own:
                ax, ay = arm[k][i]
                T0 = self._T0[k]
                cols.append((ax, ay))
                bx -= ax * T0
                by -= ay * T0
            extra = _min_sum_pair(cols, bx, by)
            if extra is None:
                raise ModelError(
                    f"segment {self.params.segments[i].name}: its cables cannot produce the "
                    f"moment ({bx:.4g}, {by:.4g}) N*mm with tensions >= pretension"
                )
            for j, k in enumerate(own):
                T[k] = (self._T0[k] + extra[j]) / Fb[k][i]
        return T

    def arm_weight(self, k: int, i: int) -> float:
        """Weight of cable k's load in segment i's moment balance: 1 in its own segment, the
        coupling gain (``Effects.coupling_gain``) in a proximal one it crosses, 0 uncoupled."""
        if self._a[k] == i:
            return 1.0
        if not self.effects.coupling or self._a[k] < i:
            return 0.0
        return self.effects.coupling_gain

    def moment_residual(self, pose: Pose, Fb: list[list[float]], T: list[float]) -> list[float]:
        """Flat (2S,) residual sum T Fbar arm - m_req (N*mm) of the moment-vector equations."""
        out = []
        coupling = self.effects.coupling
        for i in range(self.S):
            rx, ry = pose.m_req[i]
            rx, ry = -rx, -ry
            for k in self._crossing[i] if coupling else self._own[i]:
                f = T[k] * Fb[k][i] * self.arm_weight(k, i)
                ax, ay = pose.arm[k][i]
                rx += f * ax
                ry += f * ay
            out.append(rx)
            out.append(ry)
        return out

    # ------------------------------------------------------------------ along the cable
    def outside(self, k: int, T_base: float, s: float) -> tuple[float, float]:
        """(actuator tension N, delta_out mm) from the base tension: pulleys and free runs."""
        T0 = self._T0[k]
        run = self._run[k]
        T = T_base
        acc = (T - T0) * run
        for tr in self._pul_rev[k]:
            T, st = tr.to_actuator_stretch(T, s, T0)
            acc += st
            acc += (T - T0) * run
        return T, acc * self._iEA[k]

    def base_from_actuator(self, k: int, T_act: float, s: float) -> float:
        """Tension entering the base hole from the tension between actuator and first pulley."""
        T = T_act
        for tr in self._pul[k]:
            T = tr.to_robot(T, s)
        return T

    # ------------------------------------------------------------------ full chain
    def evaluate(
        self,
        xs: list[float],
        s: list[float],
        T_distal: list[float] | None = None,
        pose: Pose | None = None,
    ) -> Transfer:
        """The chain at ``xs`` with friction fractions ``s``; statics unless ``T_distal`` given."""
        P = self.pose(xs) if pose is None else pose
        Fb, Eb = self.factors(P, s)
        T = self.statics(P, Fb) if T_distal is None else list(T_distal)
        return self._along(P, Fb, Eb, T, s)

    def evaluate_measured(
        self,
        xs: list[float],
        s: list[float],
        measured_N: list[float],
        locations: list[Location],
        pose: Pose | None = None,
    ) -> Transfer:
        """The chain with load-cell tensions in place of modelled ones (NaN: use the model)."""
        P = self.pose(xs) if pose is None else pose
        Fb, Eb = self.factors(P, s)
        T_model: list[float] | None = None
        T = [0.0] * self.K
        for k in range(self.K):
            v = measured_N[k]
            if v != v:  # NaN: no reading for this cable
                if T_model is None:
                    T_model = self.statics(P, Fb)
                T[k] = T_model[k]
                continue
            Tb = v if locations[k] == "robot_base" else self.base_from_actuator(k, v, s[k])
            T[k] = Tb * math.exp(-Eb[k])
        return self._along(P, Fb, Eb, T, s)

    def cable(
        self, P: Pose, k: int, T_k: float, s_k: float, Fb_k: list[float], Eb_k: float
    ) -> tuple[float, float, float, float]:
        """(T_base, T_actuator, w, q) of cable k for its anchor tension and friction state:
        T_base = T_k exp(Ebar_k); T_actuator and delta_out from :meth:`outside`; the stretch
        inside the robot delta_in = sum_i l_i (T_k Fbar_ki - T0) / EA over the segments cable k
        crosses, w = q_geom + delta_in, q = w + delta_out (mm). It runs per cable in every
        evaluation of the chain and in the forward solver's differences.
        """
        tb = T_k * math.exp(Eb_k)
        ta, do = self.outside(k, tb, s_k)
        iEA = self._iEA[k]
        if iEA == 0.0:
            return tb, ta, P.q_geom[k] + 0.0, P.q_geom[k] + 0.0 + do
        T0 = self._T0[k]
        a_in = 0.0
        ls = self._l
        for i, f in enumerate(Fb_k):
            a_in += ls[i] * (T_k * f - T0)
        wk = P.q_geom[k] + a_in * iEA
        return tb, ta, wk, wk + do

    def _along(self, P: Pose, Fb, Eb, T, s) -> Transfer:
        K = self.K
        Tb, Ta, din, dout, w, q = [0.0] * K, [0.0] * K, [0.0] * K, [0.0] * K, [0.0] * K, [0.0] * K
        qg = P.q_geom
        cable = self.cable
        for k in range(K):
            tb, ta, wk, qk = cable(P, k, T[k], s[k], Fb[k], Eb[k])
            Tb[k] = tb
            Ta[k] = ta
            din[k] = wk - qg[k]
            dout[k] = qk - wk
            w[k] = wk
            q[k] = qk
        return Transfer(list(qg), list(T), Tb, Ta, din, dout, w, q)

    def friction_capacity(self, P: Pose, k: int) -> float:
        """ln(T_high/T_low) of cable k fully sliding at this pose (holes + pulleys at T0)."""
        cap = self._mu[k] * P.Zb[self._a[k]]
        for lnk in self._pul_lnk0[k]:  # ln kappa of each pulley at T0, in pulley order
            cap += lnk
        return cap

    def pulleys(self, k: int) -> list[PulleyTransfer]:
        """The pulley transfers of cable k, actuator -> robot order."""
        return list(self._pul[k])

    @property
    def crossing(self) -> list[list[int]]:
        """Per segment, the cables whose tension loads it (all crossing, or own if uncoupled)."""
        return self._crossing if self.effects.coupling else self._own

    @property
    def has_friction(self) -> list[bool]:
        return list(self._has_friction)

    @property
    def rigid(self) -> list[bool]:
        return list(self._rigid)

    @property
    def kEI(self) -> list[float]:
        return list(self._kEI)


def _min_sum_pair(
    cols: list[tuple[float, float]], bx: float, by: float, tol: float = 1e-9
) -> list[float] | None:
    """Extra tensions y >= 0 of least sum with sum y_j cols_j = b (statics.pretension_tensions)."""
    m = len(cols)
    scale = 1.0
    for cx, cy in cols:  # max(scale, abs(cx), abs(cy)), written out
        v = abs(cx)
        if v > scale:
            scale = v
        v = abs(cy)
        if v > scale:
            scale = v
    if abs(bx) <= tol * scale and abs(by) <= tol * scale:
        return [0.0] * m
    if m == 1:
        cx, cy = cols[0]
        y = (bx * cx + by * cy) / (cx * cx + cy * cy)
        return [y] if y >= -tol and abs(by * cx - bx * cy) <= 1e-6 * scale * scale else None
    best = None
    best_sum = math.inf
    for j in range(m - 1):
        ajx, ajy = cols[j]
        for k in range(j + 1, m):
            akx, aky = cols[k]
            det = ajx * aky - ajy * akx
            if abs(det) < 1e-14 * scale * scale:
                continue
            yj = (bx * aky - by * akx) / det
            yk = (ajx * by - ajy * bx) / det
            if yj >= -tol and yk >= -tol and yj + yk < best_sum:
                best_sum = yj + yk
                best = (j, k, yj if yj > 0.0 else 0.0, yk if yk > 0.0 else 0.0)
    if best is None:
        return None
    out = [0.0] * m
    out[best[0]] = best[2]
    out[best[1]] = best[3]
    return out
