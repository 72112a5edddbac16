"""The joint least-squares problem of :mod:`cdcr_ctl.identify.estimator`: residuals and Jacobian.

:class:`_Problem` stacks, per dwell, the tip, load-cell, moment and compatibility residuals of
the model at the measured state (Qi et al. 2023 eq. 1-4, 8-15, 23, 29-37; lost motion Yang et
al. 2022 eq. 13-17) over [free globals | per-dwell nuisance]; :func:`initial_nuisance` gives the
starting poses and tensions.

The disk friction follows the controller's law (``robot.friction_law``, a
:class:`~cdcr_ctl.model.cc_disk.friction_law.FrictionLawShape`; None: the capstan law of eq.
16-24): the chain is then a :class:`~cdcr_ctl.model.cc_disk.friction_law.LawTransfer` at rest,
every dwell being quasi-static (cable speed ~0), so a speed-dependent law's coefficient is its
at-rest value mu_k m(0) = mu_k (1 + b) and the fitted mu_disk is the Coulomb coefficient the
controller's law multiplies.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.optimize import least_squares

from cdcr_ctl.errors import ModelError
from cdcr_ctl.identify.dwell import DwellPoint
from cdcr_ctl.identify.fit_types import RESIDUAL_KINDS, FitOptions
from cdcr_ctl.identify.parameters import FitParameter, apply_values
from cdcr_ctl.model.cc_disk.friction_law import LawTransfer
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.kinematics import tip_position_fast
from cdcr_ctl.model.cc_disk.params import Effects, Location, RobotParams
from cdcr_ctl.model.cc_disk.routing import cable_matrix_x
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer

_H_VAR = 1e-6  # finite-difference step of a global unknown (log or natural units)
_H_X = 1e-7  # rad
_H_S = 1e-6
_X_BOUND = 3.2  # rad, bound of each bending-vector component
_T_MAX = 1e3  # N
#: Drive travel (mm) after which a cable's position in its play is known whatever it was at the
#: start of the run: the play operator forgets its start once the drive's range since then
#: exceeds the width b (from either end of the gap, a range >= b pushes the cable against the
#: same side). 1 mm is above any lost motion of a usable rig (issue #17 worlds: 0.2-0.4 mm);
#: the width used is the larger of this and twice the largest play assumed (``FitOptions.play_mm``,
#: else the config's backlash_mm).
PLAY_SETTLE_MM = 1.0


def dwell_transfer(
    params: RobotParams, effects: Effects, friction_law: FrictionLawShape | None
) -> ForceTransfer:
    """The force-transfer chain of a quasi-static dwell (module docstring): the capstan law's
    :class:`ForceTransfer` for None or a capstan shape, else the law's :class:`LawTransfer` with
    every cable at rest (its speeds start at 0 mm/s)."""
    if friction_law is None or friction_law.capstan:
        return ForceTransfer(params, effects)
    return LawTransfer(params, effects, friction_law)


class _Problem:
    """Residuals and Jacobian of the joint problem for one set of free globals and residual kinds.

    The unknown vector is [free globals (fit variables) | per-point nuisance blocks]; each point's
    residual rows depend on the globals and on its own block only.
    """

    def __init__(
        self,
        base: RobotParams,
        effects: Effects,
        points: Sequence[DwellPoint],
        locations: Sequence[Location],
        fps: Sequence[FitParameter],
        options: FitOptions,
        friction_law: FrictionLawShape | None = None,
    ) -> None:
        self.base = base
        self.friction_law = friction_law
        self.effects = effects
        self.points = list(points)
        self.locations = list(locations)
        self.fps = list(fps)
        self.opt = options
        S, K = base.n_segments, base.n_cables
        self.S, self.K = S, K
        self.lengths = [s.length_mm for s in base.segments]
        r = [c.routing_radius_mm for c in base.cables]
        self.unc: list[list[int]] = []  # per point: cables with an unknown friction state
        self.sig_tip: list[float] = []
        self.sig_T: list[list[float]] = []
        self.sig_q: list[list[float]] = []
        self.sig_M: list[float] = []
        for p in self.points:
            self.unc.append([k for k in range(K) if not p.s_known[k]])
            self.sig_tip.append(max(p.tip_se_mm, options.tip_floor_mm))
            sT = [max(float(p.tension_se_N[k]), options.tension_floor_N) for k in range(K)]
            self.sig_T.append(sT)
            self.sig_q.append([max(float(p.q_act_se_mm[k]), options.q_floor_mm) for k in range(K)])
            self.sig_M.append(
                max(options.moment_floor_Nmm, math.sqrt(sum((sT[k] * r[k]) ** 2 for k in range(K))))
            )
        self.play_known = self._play_known(fps)
        self.block = [2 * S + K + len(u) for u in self.unc]
        self.offsets = np.concatenate(([0], np.cumsum(self.block)))
        self._ft_key: tuple[float, ...] | None = None
        self._play_cache: dict[tuple[float, ...], list[list[float]]] = {}
        self._ft: ForceTransfer | None = None
        self.g_all = np.array([fp.to_var(fp.nominal) for fp in self.fps])
        self.set_stage(list(range(len(self.fps))), RESIDUAL_KINDS)

    def _play_known(self, fps: Sequence[FitParameter]) -> list[list[bool]]:
        """Per point and cable: whether its position in the play is known (see
        :data:`PLAY_SETTLE_MM`). The play state at the start of a run is unknown (a run that
        follows another one in the same session starts wherever that one left the cable in
        its gap), so the compatibility rows before the drive has ranged over the gap are not
        used; the mask comes from the logged drive positions only, not from the fitted
        widths, so the rows stay fixed during the fit. Everything is known when the model has
        no play and none is fitted."""
        widths = list(self.opt.play_mm or (c.backlash_mm for c in self.base.cables))
        if not any(fp.kind == "backlash" for fp in fps) and not any(w > 0 for w in widths):
            return [[True] * self.K for _ in self.points]
        settle = max(PLAY_SETTLE_MM, 2.0 * max(widths))
        span: dict[str, list[tuple[float, float]]] = {}
        out: list[list[bool]] = []
        for p in self.points:
            x = [float(v) for v in p.q_act_mm]
            prev = span.get(p.run)
            cur = []
            for k in range(self.K):
                lo, hi = prev[k] if prev is not None else (math.inf, -math.inf)
                if math.isfinite(x[k]):
                    lo, hi = min(lo, x[k]), max(hi, x[k])
                cur.append((lo, hi))
            span[p.run] = cur
            out.append([hi - lo >= settle for lo, hi in cur])
        return out

    # ------------------------------------------------------------------ layout
    def set_stage(self, free: Sequence[int], kinds: Sequence[str]) -> None:
        """Choose the free globals (indices into ``fps``) and the residual kinds."""
        self.free = list(free)
        self.kinds = frozenset(kinds)
        self.rows: list[list[tuple[str, int]]] = []  # per point: (kind, item) of each row
        for p in self.points:
            rows: list[tuple[str, int]] = []
            if "tip" in self.kinds and p.has_tip:
                rows += [("tip", a) for a in range(3)]
            if "cell" in self.kinds:
                rows += [("cell", k) for k in range(self.K) if math.isfinite(float(p.tension_N[k]))]
            if "moment" in self.kinds:
                rows += [("moment", a) for a in range(2 * self.S)]
            if "compat" in self.kinds:
                known = self.play_known[len(self.rows)]
                for k in range(self.K):
                    T = float(p.tension_N[k])
                    if (
                        known[k]
                        and math.isfinite(float(p.q_act_mm[k]))
                        and not (math.isfinite(T) and T < self.opt.slack_N)
                    ):
                        rows.append(("compat", k))
            self.rows.append(rows)
        self.row_off = np.concatenate(([0], np.cumsum([len(r) for r in self.rows])))

    @property
    def n_free(self) -> int:
        return len(self.free)

    def pack(self, nuis: np.ndarray) -> np.ndarray:
        return np.concatenate((self.g_all[self.free], nuis))

    def unpack(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g = self.g_all.copy()
        g[self.free] = z[: self.n_free]
        return g, z[self.n_free :]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = [], []
        for j in self.free:
            a, b = self.fps[j].var_bounds()
            lo.append(a)
            hi.append(b)
        for u in self.unc:
            lo += [-_X_BOUND] * (2 * self.S) + [0.0] * self.K + [-1.0] * len(u)
            hi += [_X_BOUND] * (2 * self.S) + [_T_MAX] * self.K + [1.0] * len(u)
        return np.array(lo), np.array(hi)

    # ------------------------------------------------------------------ model
    def params_of(self, g: np.ndarray) -> RobotParams:
        vals = [fp.from_var(v) for fp, v in zip(self.fps, g, strict=True)]
        return apply_values(self.base, self.fps, vals)

    def transfer(self, g: np.ndarray) -> ForceTransfer:
        key = tuple(float(v) for v in g)
        if key != self._ft_key:
            self._ft = dwell_transfer(self.params_of(g), self.effects, self.friction_law)
            self._ft_key = key
        assert self._ft is not None
        return self._ft

    def split_block(self, j: int, b: np.ndarray) -> tuple[list[float], list[float], list[float]]:
        """(xs, T, s) of point j from its nuisance block."""
        S2, K = 2 * self.S, self.K
        xs = [float(v) for v in b[:S2]]
        T = [float(v) for v in b[S2 : S2 + K]]
        s = [float(v) for v in self.points[j].s]
        for m, k in enumerate(self.unc[j]):
            s[k] = float(b[S2 + K + m])
        return xs, T, s

    def point_residual(self, ft: ForceTransfer, j: int, b: np.ndarray) -> list[float]:
        """Weighted residual rows of point j (see the module docstring)."""
        p = self.points[j]
        xs, T, s = self.split_block(j, b)
        P = ft.pose(xs)
        Fb, Eb = ft.factors(P, s)
        mom = ft.moment_residual(P, Fb, T) if "moment" in self.kinds else None
        tip = tip_position_fast(xs, self.lengths) if "tip" in self.kinds and p.has_tip else None
        cab = [ft.cable(P, k, T[k], s[k], Fb[k], Eb[k]) for k in range(self.K)]
        out = []
        for kind, a in self.rows[j]:
            if kind == "tip":
                out.append((tip[a] - float(p.tip_mm[a])) / self.sig_tip[j])
            elif kind == "cell":
                tb, ta, _, _ = cab[a]
                model = tb if self.locations[a] == "robot_base" else ta
                out.append((model - float(p.tension_N[a])) / self.sig_T[j][a])
            elif kind == "moment":
                out.append(mom[a] / self.sig_M[j])
            else:
                # The drive stands ahead of the cable by what the play leaves
                # (cdcr_ctl.model.shared.deadzone): +-b/2 once a move exceeded the gap, less at the
                # first dwell after a reversal when the step was shorter than the gap.
                play = self.play_offsets(ft)[j][a]
                q_meas = float(p.q_act_mm[a])
                if self.opt.slack_compat:
                    q_meas = max(q_meas, ft.cable(P, a, 0.0, s[a], Fb[a], Eb[a])[3])
                out.append((cab[a][3] + play - q_meas) / self.sig_q[j][a])
        return out

    def play_offsets(self, ft: ForceTransfer) -> list[list[float]]:
        """Per point and cable, drive position minus cable position through the play (mm):
        the play operator (:func:`cdcr_ctl.model.shared.deadzone.play_forward`) run over each run's
        dwells in order (between two dwells a cable moves one way, so the operator on the dwell
        positions is exact), starting centred at the run's first dwell. Cached per widths."""
        key = tuple(c.backlash_mm for c in ft.params.cables)
        hit = self._play_cache.get(key)
        if hit is not None:
            return hit
        out: list[list[float]] = []
        last: dict[str, list[float]] = {}
        for p in self.points:
            x = [float(v) for v in p.q_act_mm]
            prev = last.get(p.run)
            y = []
            for k, b in enumerate(key):
                yp = prev[k] if prev is not None else x[k]
                if not math.isfinite(x[k]):
                    y.append(yp)
                elif not math.isfinite(yp):
                    y.append(x[k])
                else:
                    y.append(min(max(yp, x[k] - 0.5 * b), x[k] + 0.5 * b))
            last[p.run] = y
            out.append(
                [x[k] - y[k] if math.isfinite(x[k] - y[k]) else 0.0 for k in range(len(key))]
            )
        if len(self._play_cache) > 64:
            self._play_cache.clear()
        self._play_cache[key] = out
        return out

    def residuals(self, z: np.ndarray) -> np.ndarray:
        g, nuis = self.unpack(z)
        ft = self.transfer(g)
        out: list[float] = []
        for j in range(len(self.points)):
            out += self.point_residual(ft, j, nuis[self.offsets[j] : self.offsets[j + 1]])
        return np.asarray(out)

    def jacobian(self, z: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Forward differences: one full evaluation per free global, and one per nuisance slot
        (all points' slot m perturbed together: point residuals are independent)."""
        r0 = self.residuals(z)
        J = np.zeros((r0.size, z.size))
        P = self.n_free
        for c in range(P):
            h = _H_VAR if z[c] + _H_VAR <= hi[c] else -_H_VAR
            zz = z.copy()
            zz[c] += h
            J[:, c] = (self.residuals(zz) - r0) / h
        g, nuis = self.unpack(z)
        ft = self.transfer(g)
        S2, K = 2 * self.S, self.K
        for m in range(max(self.block)):
            for j in range(len(self.points)):
                if m >= self.block[j]:
                    continue
                col = P + int(self.offsets[j]) + m
                hstep = _H_X if m < S2 else (1e-6 * max(1.0, abs(z[col])) if m < S2 + K else _H_S)
                if z[col] + hstep > hi[col]:
                    hstep = -hstep
                b = nuis[self.offsets[j] : self.offsets[j + 1]].copy()
                b[m] += hstep
                rj = np.asarray(self.point_residual(ft, j, b))
                a0, a1 = self.row_off[j], self.row_off[j + 1]
                J[a0:a1, col] = (rj - r0[a0:a1]) / hstep
        return J

    def solve(self, nuis0: np.ndarray, max_nfev: int) -> tuple[np.ndarray, object]:
        lo, hi = self.bounds()
        z0 = np.clip(self.pack(nuis0), lo + 1e-12, hi - 1e-12)
        # BLAS runs on one thread in every cdcr_ctl process (cdcr_ctl/blas.py): the solver's
        # SVDs (~1000 x 500) take 0.35 s so, 10 s with OpenBLAS's threads on a busy 2-core machine.
        sol = least_squares(
            self.residuals,
            z0,
            jac=lambda z: self.jacobian(z, lo, hi),
            bounds=(lo, hi),
            method="trf",
            x_scale="jac",
            max_nfev=max_nfev,
            xtol=1e-10,
            ftol=1e-10,
            gtol=1e-10,
        )
        g, nuis = self.unpack(sol.x)
        self.g_all = g
        return nuis, sol

    # ------------------------------------------------------------------ reporting helpers
    def kind_residuals(self, z: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Unweighted residuals per kind: (point index, value in the kind's unit)."""
        r = self.residuals(z)
        out: dict[str, tuple[list[int], list[float]]] = {k: ([], []) for k in RESIDUAL_KINDS}
        for j, rows in enumerate(self.rows):
            for n, (kind, a) in enumerate(rows):
                v = float(r[self.row_off[j] + n])
                if kind == "tip":
                    v *= self.sig_tip[j]
                elif kind == "cell":
                    v *= self.sig_T[j][a]
                elif kind == "moment":
                    v *= self.sig_M[j]
                else:
                    v *= self.sig_q[j][a]
                out[kind][0].append(j)
                out[kind][1].append(v)
        return {k: (np.array(i, dtype=int), np.array(v)) for k, (i, v) in out.items()}


def _rms(res: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    return {k: float(np.sqrt(np.mean(v**2))) if v.size else math.nan for k, (_, v) in res.items()}


def initial_nuisance(
    params: RobotParams,
    effects: Effects,
    points: Sequence[DwellPoint],
    locations: Sequence[Location],
    unc: Sequence[Sequence[int]],
    friction_law: FrictionLawShape | None = None,
) -> np.ndarray:
    """Starting poses (tip inversion for one segment, else the command) and anchor tensions
    (load cells through the nominal friction, else the nominal statics, else T0)."""
    ft = dwell_transfer(params, effects, friction_law)
    S, K = params.n_segments, params.n_cables
    Bpinv = np.linalg.pinv(cable_matrix_x(params))
    out: list[float] = []
    for p, u in zip(points, unc, strict=True):
        xs: list[float] = []
        if S == 1 and p.has_tip:
            px, py, pz = (float(v) for v in p.tip_mm)
            rho = math.hypot(px, py)
            th = 2.0 * math.atan2(rho, pz)  # tip of an arc: rho/z = tan(theta/2)
            ph = math.atan2(py, px)
            xs = [th * math.cos(ph), th * math.sin(ph)]
        elif np.all(np.isfinite(p.psi_cmd)):
            for i in range(S):
                th, ph = float(p.psi_cmd[i, 0]), float(p.psi_cmd[i, 1])
                xs += [th * math.cos(ph), th * math.sin(ph)]
        else:  # no commanded pose (a keypoint log): the rigid-cable inverse of eq. 4
            xs = [float(v) for v in Bpinv @ np.nan_to_num(p.q_act_mm)]
        s = [float(v) * (0.9 if k in u else 1.0) for k, v in enumerate(p.s)]
        P = ft.pose(xs)
        Fb, Eb = ft.factors(P, s)
        try:
            T_model = ft.statics(P, Fb)
        except ModelError:
            T_model = [c.pretension_N for c in params.cables]
        T = []
        for k in range(K):
            m = float(p.tension_N[k])
            if math.isfinite(m):
                tb = m if locations[k] == "robot_base" else ft.base_from_actuator(k, m, s[k])
                T.append(max(tb * math.exp(-Eb[k]), 0.0))
            else:
                T.append(max(T_model[k], 0.0))
        out += xs + T + [s[k] for k in u]
    return np.asarray(out)
