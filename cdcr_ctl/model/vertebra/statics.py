"""Gravity statics of the vertebra arm on its elastic rod (this project's addition to the fuel-tank
vertebra robot paper, which calls the resulting error "cables not taut"): the gravity potential
and its derivatives in the bending vector x, the small-deflection equilibrium of the cables
(eq. 3-5 lengths, stretch EA / L), the rod's bending stiffness EI and gravity
(:func:`statics_x`), its inverse (:func:`statics_inverse_x`), and the simulator's truth
(:func:`truth_pose`).

Units: mm, N, rad, g, N*mm^2, mm/s^2.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.vertebra.cables import (
    _cable_jacobian_and_hessian,
    joints_from_displacements,
    psi_from_xs,
    x_from_psi,
)
from cdcr_ctl.model.vertebra.forward import _psi_array
from cdcr_ctl.model.vertebra.params import (
    GRAVITY_FD_STEP_RAD,
    STATICS_MAX_ITER,
    STATICS_NEWTON_BELOW_RAD,
    STATICS_TOL_RAD,
    VertebraArm,
)

# =========================================================================== truth


def _potential_batch(arm: VertebraArm, xs: np.ndarray) -> np.ndarray:
    """Gravity potential (B,) of B poses given as bending vectors (B, N, 2): the masses of
    :func:`mass_points` in closed form (N*mm).

    A joint's n units each turn by a = theta/n about k = (-sin phi, cos phi, 0), so unit m's
    rotation is R^m = Rot(k, m a) = k k^T + cos(m a) (I - k k^T) + sin(m a) [k]x and a sum
    sum_m w_m R^m is M(C, S, W) = W k k^T + C (I - k k^T) + S [k]x with C = sum w_m cos(m a),
    S = sum w_m sin(m a), W = sum w_m. A unit is Trans(z, l0/2) R Trans(z, l0/2 + H), i.e. the
    translation t = (l0/2) e_z + (l0/2 + H) R e_z, which lies in the bending plane (k . t = 0);
    so in the joint's base frame

        end of the joint            = sum_{l<n} R^l t               = M(C2, S2, n) t,
        sum of the n disk centres   = sum_{l<n} (n - l) R^l t + sum_{m=1..n} R^m c
                                    = M(C0, S0, n(n+1)/2) t + M(C1, S1, n) c,

    c = (0, 0, -H/2) (a disk's centre below the top face of its hole; k . c = 0 too). Only
    g . p is needed: g is carried into each joint's base frame (g_i = R_{i-1}^T g) and g . p of
    the joint bases accumulates, so the chain costs a few element-wise operations per joint on
    the components (no 3x3 or 4x4 products): g . M(C, S, W) v = C g . v + S (g x k) . v for v
    perpendicular to k.
    """
    X = np.asarray(xs, dtype=float)
    B = X.shape[0]
    n_arr, half, ell, zc, mass, W = arm.potential_constants
    # per joint, independent of the chain: (B, N) arrays
    xi, yi = X[..., 0], X[..., 1]
    theta = np.hypot(xi, yi)
    straight = theta == 0.0  # phi = atan2(0, 0) = 0 there
    inv = 1.0 / np.where(straight, 1.0, theta)
    cp, sp = np.where(straight, 1.0, xi * inv), yi * inv
    a = theta / n_arr
    E = np.exp(1j * (a.T[..., None] * np.arange(W.shape[1]))) @ W  # (N, B, 3)
    C, S = E.real, E.imag  # per joint (B, 3): C0, C1, C2 and S0, S1, S2
    sa = ell * np.sin(a)
    t2 = ell * np.cos(a) + half
    ct, st = np.cos(theta), np.sin(theta)
    # probe vectors per joint: t = (sa cp, sa sp, t2), k x t = (cp t2, sp t2, -sa) (k . t = 0),
    # k x e_z = (cp, sp, 0)
    P = np.empty((*X.shape[:2], 3, 3))
    P[..., 0, 0], P[..., 0, 1], P[..., 0, 2] = sa * cp, sa * sp, t2
    P[..., 1, 0], P[..., 1, 1], P[..., 1, 2] = cp * t2, sp * t2, -sa
    P[..., 2, 0], P[..., 2, 1], P[..., 2, 2] = cp, sp, 0.0
    # Rot(k, theta)^T (eq. 1 transposed): carries g from a joint's base into its end frame
    c1 = cp * sp * (ct - 1.0)
    RT = np.empty((*X.shape[:2], 3, 3))
    RT[..., 0, 0], RT[..., 0, 1], RT[..., 0, 2] = ct * cp * cp + sp * sp, c1, -st * cp
    RT[..., 1, 0], RT[..., 1, 1], RT[..., 1, 2] = c1, cp * cp + sp * sp * ct, -st * sp
    RT[..., 2, 0], RT[..., 2, 1], RT[..., 2, 2] = st * cp, st * sp, ct
    g = np.tile(np.asarray(arm.gravity_mm_s2, dtype=float), (B, 1))  # in the joint base frame
    pg = np.zeros(B)  # g . (position of the joint base)
    V = np.zeros(B)
    for i in range(arm.n_joints):
        d = np.einsum("bpk,bk->bp", P[:, i], g)  # g . t, g . (k x t), g . (k x e_z)
        Ci, Si = C[i], S[i]
        if mass[i] > 0:
            # g . M(C1, S1, n) c = (C1 g_z + S1 g . (k x e_z)) c_z
            centres = (
                n_arr[i] * pg
                + Ci[:, 0] * d[:, 0]
                + Si[:, 0] * d[:, 1]
                + (Ci[:, 1] * g[:, 2] + Si[:, 1] * d[:, 2]) * zc[i]
            )
            V -= mass[i] * 1e-6 * centres
        pg = pg + Ci[:, 2] * d[:, 0] + Si[:, 2] * d[:, 1]
        g = np.einsum("bkl,bl->bk", RT[:, i], g)
    if arm.tip_mass_g > 0:
        V -= arm.tip_mass_g * 1e-6 * pg
    return V


def gravity_potential_Nmm(arm: VertebraArm, psi: np.ndarray) -> float:
    """V = -sum m g . p of the disks and the tip mass (N*mm; g * 1e-3 -> kg, mm/s^2 * 1e-3)."""
    return float(_potential_batch(arm, x_from_psi(_psi_array(psi, arm.n_joints))[None])[0])


def _has_gravity(arm: VertebraArm) -> bool:
    return bool(np.any(np.asarray(arm.gravity_mm_s2) != 0.0))


def gravity_torque_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    """Q = -dV/dx (2N,), N*mm per rad of bending vector, by central differences."""
    xs = np.asarray(x, dtype=float).ravel()
    n = xs.size
    if not _has_gravity(arm):
        return np.zeros(n)
    E = np.eye(n) * GRAVITY_FD_STEP_RAD
    V = _potential_batch(arm, np.concatenate((xs + E, xs - E)).reshape(2 * n, -1, 2))
    return -(V[:n] - V[n:]) / (2.0 * GRAVITY_FD_STEP_RAD)


@lru_cache(maxsize=8)
def _hessian_stencil(n: int, h: float) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Offsets (4 P, n) of the four-point stencil of every pair j <= k (P pairs), and the pairs."""
    pairs = [(j, k) for j in range(n) for k in range(j, n)]
    D = np.zeros((4 * len(pairs), n))
    for p, (j, k) in enumerate(pairs):
        for q, (sj, sk) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
            D[4 * p + q, j] += sj * h
            D[4 * p + q, k] += sk * h
    return D, pairs


def _hessian_from_stencil(V: np.ndarray, pairs: list[tuple[int, int]], n: int, h: float):
    v = V.reshape(-1, 4)
    vals = (v[:, 0] - v[:, 1] - v[:, 2] + v[:, 3]) / (4.0 * h * h)
    H = np.zeros((n, n))
    jj, kk = np.array(pairs).T
    H[jj, kk] = vals
    H[kk, jj] = vals
    return H


def gravity_hessian_x(arm: VertebraArm, x: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """d^2 V / dx^2 (2N x 2N, N*mm/rad^2), four-point stencil."""
    xs = np.asarray(x, dtype=float).ravel()
    n = xs.size
    D, pairs = _hessian_stencil(n, h)
    V = _potential_batch(arm, (xs + D).reshape(len(D), -1, 2))
    return _hessian_from_stencil(V, pairs, n, h)


@lru_cache(maxsize=8)
def _solver_stencil(n: int, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets (1 + 2n + n(n-1)/2, n) for :func:`_gravity_torque_and_hessian`: 0, +-h e_j, then
    h (e_j + e_k) for j < k; and the pair indices (j, k)."""
    jj, kk = np.triu_indices(n, 1)
    E = np.eye(n) * h
    D = np.concatenate((np.zeros((1, n)), E, -E, E[jj] + E[kk]))
    return D, jj, kk


def _gravity_torque_and_hessian(arm: VertebraArm, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(:func:`gravity_torque_x`, an approximate gravity Hessian) at ``x`` from ONE batch of
    1 + 2n + n(n-1)/2 potentials: the torque by the same central differences; the Hessian by
    the three-point second difference on the diagonal and a forward mixed difference
    (V(x + h e_j + h e_k) - V(x + h e_j) - V(x + h e_k) + V(x)) / h^2 off it (O(h), ~1e-4
    relative at h = 1e-4): it only sets the statics' Newton matrix and stability check, never
    the equilibrium."""
    xs = np.asarray(x, dtype=float).ravel()
    n = xs.size
    h = GRAVITY_FD_STEP_RAD
    D, jj, kk = _solver_stencil(n, h)
    V = _potential_batch(arm, (xs + D).reshape(len(D), -1, 2))
    v0, vp, vm, vpp = V[0], V[1 : n + 1], V[n + 1 : 2 * n + 1], V[2 * n + 1 :]
    Q = -(vp - vm) / (2.0 * h)
    H = np.diag((vp - 2.0 * v0 + vm) / (h * h))
    off = (vpp - vp[jj] - vp[kk] + v0) / (h * h)
    H[jj, kk] = off
    H[kk, jj] = off
    return Q, H


def statics_x(
    arm: VertebraArm, x_kin: np.ndarray, dx_guess: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Small-deflection equilibrium (bending vectors (N, 2), cable tensions (C,)).

    At the kinematic pose x_kin (from the cable displacements) every cable is at its pretension;
    the rod wants x = 0 with stiffness EI / L_joint per joint; gravity loads the disks. With
    J = :func:`cable_jacobian_x`, k = EA / L_total, K_g = sum T0 d^2 L / dx^2
    (:func:`cable_hessian_x`; the pretension's geometric stiffness, negative: it compresses the
    rod like a column), stationarity of
    sum [T0 L + k/2 (L - L(x_kin))^2] + sum EI/(2 L_i) |x_i|^2 + V_gravity gives

        F(dx) = (J^T k J + K_g + K_rod) dx + J^T T0 + K_rod x_kin - Q(x_kin + dx) = 0

    with the cable lengths linearised at x_kin and the gravity moment Q at the sagged pose,
    solved by Newton (dF/ddx = J^T k J + K_g + K_rod + d^2 V/dx^2 at the iterate,
    :func:`_gravity_torque_and_hessian`; once a step is below :data:`STATICS_NEWTON_BELOW_RAD`
    the last Hessian is kept, which changes the convergence rate, not the solution) from
    ``dx_guess`` (default 0, every cable taut; with a guess, e.g. the last step's sag, (2N,) or
    (N, 2), the cables taut at the guess). Cables whose tension would go negative go slack
    (active set) - the paper's "cables not taut" error. Raises :class:`ModelError` when there is
    no stable equilibrium.
    """
    x0 = np.asarray(x_kin, dtype=float).ravel()
    n = x0.size
    J, L_hess = _cable_jacobian_and_hessian(arm, x0)  # dL/dx, d^2 L_k / dx^2 per cable
    k = arm.cable_stiffness
    T0 = arm.pretensions
    K_rod = arm.rod_stiffness
    gravity = _has_gravity(arm)
    Q, H = np.zeros(n), np.zeros((n, n))
    if dx_guess is None:
        dx = np.zeros(n)
        active = np.ones(T0.shape, dtype=bool)  # every cable taut (a zero pretension too)
    else:  # the cables the guess leaves taut
        dx = np.asarray(dx_guess, dtype=float).ravel().copy()
        active = (T0 + k * (J @ dx)) >= 0.0
    K = Ja = None
    far = True
    last_change = math.inf  # the previous step with the same active set
    seen = {active.tobytes()}
    for _ in range(STATICS_MAX_ITER):
        new_matrix = far or K is None
        if K is None:
            Ja = J[active]
            Kg = np.tensordot(T0[active], L_hess[active], axes=1)  # slack cables drop out
            K = Ja.T @ (k[active, None] * Ja) + Kg + K_rod
            JT0 = Ja.T @ T0[active]
        if gravity:
            if far:
                Q, H = _gravity_torque_and_hessian(arm, x0 + dx)
            else:  # near the solution: the last Hessian (same fixed point, fewer potentials)
                Q = gravity_torque_x(arm, x0 + dx)
        A = K + H
        if new_matrix and np.linalg.eigvalsh(0.5 * (A + A.T)).min() <= 0.0:
            raise ModelError(
                "statics: no stable equilibrium (slack cables, or pretension or "
                "gravity buckling the rod)"
            )
        F = K @ dx + JT0 + K_rod @ x0 - Q
        dx_new = dx - np.linalg.solve(A, F)
        new_active = (T0 + k * (J @ dx_new)) >= 0.0
        change = float(np.max(np.abs(dx_new - dx)))
        far = change > STATICS_NEWTON_BELOW_RAD
        dx = dx_new
        if np.array_equal(new_active, active):
            # converged: this step was below the tolerance, or two steps on the same active
            # set show a contraction (rate = change / last_change < 1/2) so fast that the
            # remaining error, about change * rate, is
            rate = change / last_change if math.isfinite(last_change) else 1.0
            if change < STATICS_TOL_RAD or (rate < 0.5 and change * rate < STATICS_TOL_RAD):
                break
            last_change = change
        elif new_active.tobytes() in seen:
            # the active set cycles: the cables that flip sit on the slack threshold
            both = active & new_active
            dx = _statics_on_kink(arm, x0, J, L_hess, both, active ^ new_active, dx)
            tension = np.where(both, T0 + k * (J @ dx), 0.0)
            return (x0 + dx).reshape(-1, 2), tension
        else:
            seen.add(new_active.tobytes())
            active, K, last_change = new_active, None, math.inf
    else:
        raise ModelError("statics did not converge")
    tension = np.where(active, T0 + k * (J @ dx), 0.0)
    return (x0 + dx).reshape(-1, 2), tension


def _statics_on_kink(
    arm: VertebraArm,
    x0: np.ndarray,
    J: np.ndarray,
    L_hess: np.ndarray,
    taut: np.ndarray,
    edge: np.ndarray,
    dx: np.ndarray,
) -> np.ndarray:
    """The equilibrium of :func:`statics_x` when its active set cycles (bool masks: ``taut``
    cables, ``edge`` cables that flip): taut, an edge cable's tension T0 + k J dx is negative;
    slack, it is stretched. The model switches the edge cable's force J^T T and its
    pretension's geometric stiffness T0 d^2L/dx^2 off together, so neither set holds; the
    equilibrium sits on the switching surface (Filippov): each edge cable exactly at zero
    tension, T0 + k J dx = 0, its geometric stiffness entering with a weight w in [0, 1].
    Newton on (dx, w) from the cycling iterate; returns dx. Raises :class:`ModelError` if the
    weights leave [0, 1] (no such equilibrium)."""
    n = x0.size
    k, T0, K_rod = arm.cable_stiffness, arm.pretensions, arm.rod_stiffness
    Jb = J[taut]
    K_base = Jb.T @ (k[taut, None] * Jb) + np.tensordot(T0[taut], L_hess[taut], axes=1) + K_rod
    JT0 = Jb.T @ T0[taut]
    idx = np.nonzero(edge)[0]
    m = idx.size
    Ge = T0[idx, None, None] * L_hess[idx]  # (m, n, n) geometric stiffness of each edge cable
    w = np.full(m, 0.5)
    gravity = _has_gravity(arm)
    Q, H = np.zeros(n), np.zeros((n, n))
    for _ in range(STATICS_MAX_ITER):
        if gravity:
            Q, H = _gravity_torque_and_hessian(arm, x0 + dx)
        Kw = K_base + np.tensordot(w, Ge, axes=1)
        R = np.concatenate((Kw @ dx + JT0 + K_rod @ x0 - Q, T0[idx] + k[idx] * (J[idx] @ dx)))
        A = np.zeros((n + m, n + m))
        A[:n, :n] = Kw + H
        A[:n, n:] = (Ge @ dx).T
        A[n:, :n] = k[idx, None] * J[idx]
        step = np.linalg.solve(A, -R)
        dx, w = dx + step[:n], w + step[n:]
        if float(np.max(np.abs(step[:n]))) < STATICS_TOL_RAD:
            break
    else:
        raise ModelError("statics did not converge (cables on the slack threshold)")
    if np.any(w < -1e-9) or np.any(w > 1.0 + 1e-9):
        raise ModelError("statics: no equilibrium with the cables on the slack threshold")
    return dx


def truth_pose(
    arm: VertebraArm,
    q_mm: np.ndarray,
    statics: bool = True,
    guess_x: np.ndarray | None = None,
    phi_if_straight: np.ndarray | None = None,
) -> np.ndarray:
    """The simulator's truth: joint poses (N, 2) rows (theta, phi) for cable displacements
    ``q_mm`` (mm pulled in, cable order): kinematics (inverse of eq. 5, proximal first), then
    with ``statics`` the rod, cable elasticity, pretension, slack and gravity sag of
    :func:`statics_x`. ``guess_x`` warm-starts the solver (the last bending vectors)."""
    q = np.asarray(q_mm, dtype=float)
    if q.shape != (arm.n_cables,):
        raise ModelError(f"need {arm.n_cables} cable displacements, got shape {q.shape}")
    x = joints_from_displacements(arm, q, guess_x)
    if statics:
        x = statics_x(arm, x)[0]
    return psi_from_xs(x, phi_if_straight)


def statics_inverse_x(arm: VertebraArm, x_target: np.ndarray) -> np.ndarray:
    """x_kin such that :func:`statics_x` (x_kin) = ``x_target`` (fixed point; compensation of the
    sag: command the cables of x_kin to end at x_target)."""
    target = np.asarray(x_target, dtype=float).reshape(-1, 2)
    pre = target.copy()
    sag = None
    for _ in range(STATICS_MAX_ITER):
        x = statics_x(arm, pre, sag)[0]
        sag = x - pre
        err = target - x
        pre = pre + err
        if float(np.max(np.abs(err))) < STATICS_TOL_RAD:
            return pre
    raise ModelError("statics inverse did not converge (sag too large for small deflection)")


def statics_inverse_step(arm: VertebraArm, x_target: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """One fixed-point step of :func:`statics_inverse_x` from ``guess`` (the control loop's warm
    start: its error is |d sag / d x| times the change of the sag offset since the last tick)."""
    target = np.asarray(x_target, dtype=float).reshape(-1, 2)
    pre = np.asarray(guess, dtype=float).reshape(-1, 2)
    return pre + (target - statics_x(arm, pre)[0])
