"""Forward static solve (stateless): actuator displacements -> pose and tensions.

:class:`ForwardModel` solves moment balance (Qi et al. 2023 eq. 9-15), cable compatibility
(eq. 33-37) and the friction active set by Newton's method; see
:mod:`cdcr_ctl.model.cc_disk.forward` for the equations.
:class:`~cdcr_ctl.model.cc_disk.forward.result.ForwardResult` is one solved pose.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dgetrf, dgetrs

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.forward.result import ForwardResult, _amax, pack_result
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams
from cdcr_ctl.model.cc_disk.routing import cable_matrix_x
from cdcr_ctl.model.cc_disk.tension_chain import Transfer
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer, Pose
from cdcr_ctl.model.shared.friction import FrictionState, direction_update

STICK, SLIDE, SLACK, FREE = "stick", "slide", "slack", "free"
_H_X = 1e-7  # rad, finite-difference step of the bending vectors
_H_S = 1e-7  # finite-difference step of the friction fraction
_MODE_ROUNDS = 12
_MAX_DX = 0.3  # rad, largest change of a bending vector component per Newton step
#: A stepper that cannot solve a step at once splits it into up to 2**SUBSTEP_LEVELS sub-steps.
SUBSTEP_LEVELS = 4


class ForwardModel:
    """Solve the static pose for actuator displacements (stateless; see :class:`ForwardStepper`)."""

    def __init__(
        self,
        params: RobotParams,
        effects: Effects | None = None,
        tol: float = 1e-11,
        max_newton: int = 40,
    ) -> None:
        self.params = params
        self.effects = Effects() if effects is None else effects
        self.ft = ForceTransfer(params, self.effects)
        self.S, self.K = params.n_segments, params.n_cables
        rigid = self.ft.rigid
        if any(rigid) and not all(rigid):
            raise ModelError("mixing rigid (EA = inf) and elastic cables is not supported")
        self.rigid = all(rigid)
        self.tol = tol
        self.max_newton = max_newton
        self._B = cable_matrix_x(params)
        self._Bpinv = np.linalg.pinv(self._B)
        self._lengths = [s.length_mm for s in params.segments]
        kEI = max(self.ft.kEI)
        r = max(c.routing_radius_mm for c in params.cables)
        self._w_mom = 1.0 / kEI  # N*mm -> rad
        self._w_len = 1.0 / r  # mm -> rad
        self._T_scale = max(1.0, max(c.pretension_N for c in params.cables))
        self._Jraw: np.ndarray | None = None  # last raw Jacobian (chord Newton, warm start)
        self._slow = True
        # LU factors of the last assembled Jacobian and what it was assembled from (the raw
        # Jacobian's generation and the modes): chord Newton steps reuse them (performance only)
        self._jac_gen = 0
        self._lu: tuple | None = None
        self._lu_key: tuple | None = None
        # the last _raw evaluation, its z and force transfer (performance only)
        self._raw_z: list[float] | None = None
        self._raw_ft: ForceTransfer | None = None
        self._raw_out: tuple | None = None

    # ------------------------------------------------------------------ public
    def solve(
        self,
        q_act_mm: np.ndarray,
        state: FrictionState | None = None,
        x_guess: np.ndarray | None = None,
        T_guess: np.ndarray | None = None,
        modes_hint: tuple[str, ...] | None = None,
        q_guess: list[float] | None = None,
    ) -> ForwardResult:
        """Pose, tensions and new friction state for cable displacements ``q_act_mm`` (K,).

        ``q_act_mm`` is the cable pulled in at the actuator (after any actuator effects), mm.
        ``state`` is the friction state before this step (default: straight, nothing mobilised);
        ``x_guess``/``T_guess`` warm-start bending vectors and anchor tensions, ``modes_hint`` the
        cable modes (``stick``/``slide``/``slack``/``free``). ``q_guess``: the cable
        displacements (mm) the guess solves, when known (a predictor's); the guess is then moved
        to ``q_act_mm`` by one chord step of the last Jacobian before the first evaluation
        (:meth:`_linear_move`; performance only). Raises :class:`ModelError` when no
        consistent solution is found (e.g. a segment whose own cables all went slack).
        """
        K, S = self.K, self.S
        if isinstance(q_act_mm, list) and len(q_act_mm) == K:
            q_act = [float(v) for v in q_act_mm]
        else:
            q_act = [float(v) for v in np.asarray(q_act_mm, dtype=float).reshape(K)]
        st = FrictionState.initial(K) if state is None else state
        if self.rigid:
            return self._solve_rigid(q_act, st, x_guess)
        x0 = [0.0] * (2 * S) if x_guess is None else [float(v) for v in x_guess]
        T0 = (
            [c.pretension_N for c in self.params.cables]
            if T_guess is None
            else [float(v) for v in T_guess]
        )
        z = x0 + T0 + [float(v) for v in st.s]
        w_prev = list(st.w_mm)
        modes = list(modes_hint) if modes_hint is not None else [STICK] * K
        if q_guess is not None and self._Jraw is not None:
            z = self._linear_move(z, q_guess, q_act, modes)
            x0 = z[: 2 * S]
        P = self.ft.pose(x0)
        sigma = [1.0 if v >= 0 else -1.0 for v in st.s]
        hold = list(st.s)
        has_friction = self.ft.has_friction
        for k in range(K):
            if not has_friction[k] or self.ft.friction_capacity(P, k) < 1e-12:
                if modes[k] != SLACK:
                    modes[k] = FREE
            elif modes[k] == FREE:
                modes[k] = STICK
        total_it = 0
        seen: set[tuple[str, ...]] = {tuple(modes)}
        one_at_a_time = False
        rounds = _MODE_ROUNDS
        r = 0
        while True:
            z, it, res, raw = self._newton(z, q_act, w_prev, modes, sigma, hold)
            total_it += it
            changed = self._update_modes(
                z, q_act, w_prev, modes, sigma, hold, one_at_a_time, raw=raw
            )
            if not changed:
                break
            r += 1
            key = tuple(modes)
            if key in seen and not one_at_a_time:
                # the active set cycles (changing every violated mode at once flips the others
                # back): from here on change only the most violated mode per round
                one_at_a_time = True
                rounds = r + _MODE_ROUNDS + 3 * K
            seen.add(key)
            if r >= rounds:
                if res > 1e-6:
                    raise ModelError("forward model: friction/slack modes did not settle")
                break
        if res > 1e-6:
            raise ModelError(f"forward model did not converge (residual {res:.3g})")
        return self._result(z, modes, total_it, res, w_prev, raw)

    def _linear_move(
        self, z: list[float], q_from: list[float], q_to: list[float], modes: list[str]
    ) -> list[float]:
        """``z`` (a guess that solves cable displacements ``q_from``, mm) moved to ``q_to`` by
        one chord step of the last Jacobian, with no evaluation (a warm start only).

        At a solution for q_from the residual for q_to is, to first order, only the cable
        compatibility rows' (q_from - q_to) / r (stick, slide and moment rows unchanged, slack
        cables have no compatibility row), so dz = -J^-1 r moves z along the linearised
        solution path. The Newton iteration then converges from there to the tolerance as
        from any start: the solution does not depend on this step, only the work does.
        """
        S2, K = 2 * self.S, self.K
        r = np.zeros(S2 + 2 * K)
        for k in range(K):
            if modes[k] != SLACK:
                r[S2 + k] = (q_from[k] - q_to[k]) * self._w_len
        dz = self._step(modes, r)
        big = _amax(dz[:S2]) if S2 else 0.0
        if big > _MAX_DX:  # the trust region of the Newton steps
            dz *= _MAX_DX / big
        return [a + b for a, b in zip(z, dz.tolist(), strict=True)]

    # ------------------------------------------------------------------ rigid cables
    def _solve_rigid(
        self, q_act: list[float], st: FrictionState, x_guess: np.ndarray | None
    ) -> ForwardResult:
        K = self.K
        if self.effects.geometry == "cc":
            x = self._Bpinv @ np.asarray(q_act)
        else:
            x = np.zeros(2 * self.S) if x_guess is None else np.asarray(x_guess, dtype=float)
            for _ in range(50):
                P = self.ft.pose(x.tolist())
                r = np.asarray(P.q_geom) - np.asarray(q_act)
                J = self._arm_matrix(P)
                dx = np.linalg.lstsq(J, -r, rcond=None)[0]
                x = x + dx
                if np.max(np.abs(dx)) < 1e-14:
                    break
        xs = x.tolist()
        P = self.ft.pose(xs)
        s_new = [direction_update(st.s[k], P.q_geom[k] - st.w_mm[k], 1e-12) for k in range(K)]
        res = self.ft.evaluate(xs, s_new, pose=P)
        resid = float(np.max(np.abs(np.asarray(res.q_geom) - np.asarray(q_act))))
        state = FrictionState(s=tuple(s_new), w_mm=tuple(res.w))
        modes = tuple(SLIDE if abs(v) == 1.0 else STICK for v in s_new)
        return pack_result(xs, res, state, modes, 0, resid, self._lengths)

    def _arm_matrix(self, P: Pose) -> np.ndarray:
        J = np.zeros((self.K, 2 * self.S))
        for k in range(self.K):
            for i, (ax, ay) in enumerate(P.arm[k]):
                J[k, 2 * i] = ax
                J[k, 2 * i + 1] = ay
        return J

    def forget_evaluation(self) -> None:
        """Drop the kept evaluation of :meth:`_raw`: for a caller that changed the force
        transfer's coefficients in place (a speed-dependent friction law)."""
        self._raw_z = None

    # ------------------------------------------------------------------ elastic cables
    def _raw(self, z: list[float]):
        """Pose, factors and per-cable (Tb, Ta, w, q) at z = [x, T, s].

        A pure function of ``z`` (and of the force transfer ``ft``): the last evaluation is kept
        and given again for the same z and ft (performance only). A stepper's next solve starts
        where the last one ended, so its first evaluation is the last one of the previous solve.
        Callers do not mutate what it returns.
        """
        if z == self._raw_z and self.ft is self._raw_ft:
            return self._raw_out
        out = self._raw_eval(z)
        self._raw_z, self._raw_ft, self._raw_out = list(z), self.ft, out
        return out

    def _raw_eval(self, z: list[float]):
        S2, K = 2 * self.S, self.K
        xs = z[:S2]
        T = z[S2 : S2 + K]
        # beyond +-3 a stuck cable is far past sliding anyway; clamping keeps exp() finite
        s = [-3.0 if v < -3.0 else (3.0 if v > 3.0 else v) for v in z[S2 + K :]]
        P = self.ft.pose(xs)
        Fb, Eb = self.ft.factors(P, s)
        mom = self.ft.moment_residual(P, Fb, T)
        cab = [self.ft.cable(P, k, T[k], s[k], Fb[k], Eb[k]) for k in range(K)]
        return P, Fb, Eb, mom, cab

    def _residual(self, raw, z, q_act, w_prev, modes, sigma, hold) -> np.ndarray:
        """Scaled residual [moments (2S), compatibility (K), friction (K)], rad-equivalent
        (built as floats, one array at the end)."""
        _, _, _, mom, cab = raw
        S2, K = 2 * self.S, self.K
        w_mom, w_len = self._w_mom, self._w_len
        r = [v * w_mom for v in mom]
        fr = []
        for k in range(K):
            m = modes[k]
            if m == SLACK:
                r.append(z[S2 + k] / self._T_scale)
            else:
                r.append((cab[k][3] - q_act[k]) * w_len)
            if m == STICK:
                fr.append((cab[k][2] - w_prev[k]) * w_len)
            elif m == SLIDE:
                fr.append(z[S2 + K + k] - sigma[k])
            else:
                fr.append(z[S2 + K + k] - hold[k])
        return np.array(r + fr)

    def _jacobian(self, raw, z, modes) -> np.ndarray:
        """Jacobian of the raw functions [mom (2S), q (K), w (K)] w.r.t. z = [x, T, s]."""
        S2, K = 2 * self.S, self.K
        n = S2 + 2 * K
        J = np.zeros((S2 + 2 * K, n))
        P, Fb, Eb, mom, cab = raw
        base = np.concatenate((mom, [c[3] for c in cab], [c[2] for c in cab]))
        for j in range(S2):
            zz = list(z)
            zz[j] += _H_X
            _, _, _, m2, c2 = self._raw(zz)
            J[:, j] = (np.concatenate((m2, [c[3] for c in c2], [c[2] for c in c2])) - base) / _H_X
        T = z[S2 : S2 + K]
        s = z[S2 + K :]
        crossing = self.ft.crossing
        for k in range(K):
            # T_k column: mom rows exactly, cable rows by a central difference
            for i in range(self.S):
                if k in crossing[i]:
                    ax, ay = P.arm[k][i]
                    w = Fb[k][i] * self.ft.arm_weight(k, i)
                    J[2 * i, S2 + k], J[2 * i + 1, S2 + k] = w * ax, w * ay
            h = 1e-6 * max(1.0, abs(T[k]))
            cp = self.ft.cable(P, k, T[k] + h, s[k], Fb[k], Eb[k])
            cm = self.ft.cable(P, k, T[k] - h, s[k], Fb[k], Eb[k])
            J[S2 + k, S2 + k] = (cp[3] - cm[3]) / (2 * h)
            J[S2 + K + k, S2 + k] = (cp[2] - cm[2]) / (2 * h)
            # s_k column (every cable with friction, so a cached Jacobian serves any mode)
            if self.ft.has_friction[k]:
                sp, sm = s[k] + _H_S, s[k] - _H_S
                rp, ep = self.ft.factors_k(P, k, sp)
                rm, em = self.ft.factors_k(P, k, sm)
                for i in range(self.S):
                    if k in crossing[i]:
                        ax, ay = P.arm[k][i]
                        d = T[k] * (rp[i] - rm[i]) / (2 * _H_S) * self.ft.arm_weight(k, i)
                        J[2 * i, S2 + K + k] = d * ax
                        J[2 * i + 1, S2 + K + k] = d * ay
                cp = self.ft.cable(P, k, T[k], sp, rp, ep)
                cm = self.ft.cable(P, k, T[k], sm, rm, em)
                J[S2 + k, S2 + K + k] = (cp[3] - cm[3]) / (2 * _H_S)
                J[S2 + K + k, S2 + K + k] = (cp[2] - cm[2]) / (2 * _H_S)
        return J

    def _assemble(self, Jraw: np.ndarray, modes) -> np.ndarray:
        S2, K = 2 * self.S, self.K
        J = np.zeros_like(Jraw)
        J[:S2] = Jraw[:S2] * self._w_mom
        for k in range(K):
            m = modes[k]
            if m == SLACK:
                J[S2 + k, S2 + k] = 1.0 / self._T_scale
            else:
                J[S2 + k] = Jraw[S2 + k] * self._w_len
            if m == STICK:
                J[S2 + K + k] = Jraw[S2 + K + k] * self._w_len
            else:
                J[S2 + K + k, S2 + K + k] = 1.0
        return J

    def _newton(self, z, q_act, w_prev, modes, sigma, hold):
        S2, K = 2 * self.S, self.K
        z = list(z)
        for k in range(K):  # fixed fractions enter exactly
            if modes[k] == SLIDE:
                z[S2 + K + k] = sigma[k]
            elif modes[k] in (SLACK, FREE):
                z[S2 + K + k] = hold[k]
            if modes[k] == SLACK:
                z[S2 + k] = 0.0
        raw = self._raw(z)
        r = self._residual(raw, z, q_act, w_prev, modes, sigma, hold)
        norm = _amax(r)
        it = 0
        need_jac = self._Jraw is None or self._slow
        while norm > self.tol and it < self.max_newton:
            it += 1
            # chord Newton: reuse the last Jacobian while it keeps converging fast
            fresh = need_jac or self._Jraw is None
            if fresh:
                self._Jraw = self._jacobian(raw, z, modes)
                self._jac_gen += 1
            dz = self._step(modes, r)
            big = _amax(dz[:S2]) if S2 else 0.0
            if big > _MAX_DX:  # trust region on the pose
                dz *= _MAX_DX / big
            alpha = 1.0
            f0 = float(r @ r)
            accepted = False
            # Python floats (numpy scalars in z would make every operation of the chain
            # several times slower; the same IEEE doubles either way)
            dzl = dz.tolist()
            while alpha >= 1e-4:
                zn = [a + alpha * b for a, b in zip(z, dzl, strict=True)]
                try:
                    rawn = self._raw(zn)
                    rn = self._residual(rawn, zn, q_act, w_prev, modes, sigma, hold)
                    fn = float(rn @ rn)
                except (OverflowError, ValueError, ZeroDivisionError):
                    fn = math.inf
                if math.isfinite(fn) and fn <= (1.0 - 1e-4 * alpha) * f0:
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted:
                if fresh:
                    break  # stagnated even with a fresh Jacobian
                need_jac = True
                continue
            z, raw, r = zn, rawn, rn
            new_norm = _amax(r)
            self._slow = need_jac = new_norm > 0.1 * norm
            norm = new_norm
            # a stuck cable that needs far more than full friction will slide: stop early
            far = False
            for k in range(K):
                if modes[k] == STICK and abs(z[S2 + K + k]) > 2.0:
                    far = True
            if far:
                break
        return z, it, norm, raw

    def _step(self, modes, r: np.ndarray) -> np.ndarray:
        """Newton step dz solving J dz = -r, J the assembled Jacobian of ``modes``.

        J is square (2S + 2K); its LU factors are kept while neither the raw Jacobian nor the
        modes change (chord Newton reuses them: one O(n^2) solve per step). A singular J falls
        back to least squares (minimum-norm step), as before.
        """
        key = (self._jac_gen, tuple(modes))
        if self._lu_key != key:
            J = self._assemble(self._Jraw, modes)
            self._lu_key = key
            # LAPACK getrf directly: no warnings machinery (not thread-safe), info > 0 on an
            # exactly zero pivot
            lu, piv, info = dgetrf(J)
            d = np.abs(np.diag(lu))
            # a pivot far below the largest (relative to float64 precision) is singular
            ok = info == 0 and bool(np.all(np.isfinite(d))) and d.min() > 1e-13 * d.max()
            self._lu = (lu, piv) if ok else (None, J)
        lu, other = self._lu
        if lu is not None:
            dz, info = dgetrs(lu, other, -r)
            if info == 0:
                return dz
            return np.linalg.lstsq(self._assemble(self._Jraw, modes), -r, rcond=None)[0]
        return np.linalg.lstsq(other, -r, rcond=None)[0]

    def _update_modes(
        self, z, q_act, w_prev, modes, sigma, hold, one_at_a_time=False, raw=None
    ) -> bool:
        """Change the modes whose conditions ``z`` violates; all of them, or with
        ``one_at_a_time`` only the most violated one (scaled like the residuals: rad-equivalent).
        ``raw``: :meth:`_raw` at ``z`` if already computed. Returns whether a mode changed."""
        S2, K = 2 * self.S, self.K
        P, Fb, Eb, _, cab = self._raw(z) if raw is None else raw
        tol_w = 1e-9
        changes: list[tuple[float, int, str, float]] = []  # (violation, cable, mode, value)
        for k in range(K):
            T_k = z[S2 + k]
            s_k = z[S2 + K + k]
            m = modes[k]
            if m != SLACK and T_k < -1e-9:
                changes.append((-T_k / self._T_scale, k, SLACK, 0.0))
                continue
            if m == SLACK:
                # taut again when the cable at zero tension would be shorter than its path.
                # A slack cable carries no friction, so it re-engages sliding in the pull
                # direction (no stick memory survives slack): FREE with s = +1 for this step.
                _, _, _, q0 = self.ft.cable(P, k, 0.0, s_k, Fb[k], Eb[k])
                if q_act[k] > q0 + 1e-12:
                    changes.append(((q_act[k] - q0) * self._w_len, k, FREE, 0.0))
                continue
            if m == STICK and abs(s_k) > 1.0 + 1e-12:
                changes.append((abs(s_k) - 1.0, k, SLIDE, 1.0 if s_k > 0 else -1.0))
            elif m == SLIDE and (cab[k][2] - w_prev[k]) * sigma[k] < -tol_w:
                changes.append((-(cab[k][2] - w_prev[k]) * sigma[k] * self._w_len, k, STICK, 0.0))
        if not changes:
            return False
        if one_at_a_time:
            changes = [max(changes)]
        for _, k, mode, value in changes:
            modes[k] = mode
            if mode == SLIDE:
                sigma[k] = value
            elif mode == FREE and self.ft.has_friction[k]:
                hold[k] = 1.0
        return True

    def _result(self, z, modes, it, res, w_prev, raw=None) -> ForwardResult:
        """The solved pose at ``z``. ``raw``: :meth:`_raw` at ``z`` (the last Newton
        evaluation); when no cable is slack and every friction fraction is within [-1, 1], the
        clamped T and s below equal the ones ``raw`` used, so its pose and cables are the chain
        :meth:`ForceTransfer.evaluate` would compute again (the same calls on the same floats):
        taken as they are (performance only)."""
        S2, K = 2 * self.S, self.K
        xs = z[:S2]
        T = [max(0.0, v) if modes[k] == SLACK else v for k, v in enumerate(z[S2 : S2 + K])]
        s = [max(-1.0, min(1.0, v)) for v in z[S2 + K :]]
        if raw is not None and SLACK not in modes and s == z[S2 + K :]:
            P, _, _, _, cab = raw
            qg = P.q_geom
            w = [c[2] for c in cab]
            q = [c[3] for c in cab]
            tr = Transfer(
                list(qg),
                list(T),
                [c[0] for c in cab],
                [c[1] for c in cab],
                [w[k] - qg[k] for k in range(K)],
                [q[k] - w[k] for k in range(K)],
                w,
                q,
            )
        else:
            P = self.ft.pose(xs)
            tr = self.ft.evaluate(xs, s, T_distal=T, pose=P)
        for k in range(K):
            if modes[k] == FREE:
                s[k] = direction_update(s[k], tr.w[k] - w_prev[k], 1e-12)
        state = FrictionState(s=tuple(s), w_mm=tuple(tr.w))
        return pack_result(xs, tr, state, tuple(modes), it, res, self._lengths)
