"""Gravity statics of the universal-joint arm (this project's addition to Yang et al. 2022; NOTES):
the gravity potential of the links (:func:`mass_points` of eq. 1-2), its torque and Hessian, and
the small-deflection equilibrium of the cable-held arm (:func:`statics_angles`,
:func:`small_deflection`) with its fixed-point inverse (:func:`statics_inverse`). Cable
stiffness EA / L around the pretension, eq. 4-12's Jacobian and Hessian.

Units: mm, N, rad, g, N*mm, mm/s^2.
"""

from __future__ import annotations

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.ujoint.kinematics import _as_theta, cable_jacobian_hessian
from cdcr_ctl.model.ujoint.params import (
    GRAVITY_FD_STEP_RAD,
    STATICS_MAX_ITER,
    STATICS_TOL_RAD,
    UJointArm,
)


# =========================================================================== statics
def _potential_batch(arm: UJointArm, thetas: np.ndarray) -> np.ndarray:
    """Gravity potential (B,) of B poses (B, N, 2) at once: the chain of :func:`mass_points`
    with batched 4x4 products (the finite differences below evaluate many poses)."""
    th = np.asarray(thetas, dtype=float)
    B = th.shape[0]
    g = np.asarray(arm.gravity_mm_s2, dtype=float)
    T = np.broadcast_to(np.eye(4), (B, 4, 4)).copy()
    T[:, 2, 3] = arm.base_link_mm
    V = np.zeros(B)
    for n, seg in enumerate(arm.segments):
        ca, sa = np.cos(th[:, n, 0]), np.sin(th[:, n, 0])
        cb, sb = np.cos(th[:, n, 1]), np.sin(th[:, n, 1])
        A = np.zeros((B, 4, 4))
        # Rx(a) Ry(b)
        A[:, 0, 0], A[:, 0, 2] = cb, sb
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2] = sa * sb, ca, -sa * cb
        A[:, 2, 0], A[:, 2, 1], A[:, 2, 2] = -ca * sb, sa, ca * cb
        A[:, 3, 3] = 1.0
        d = seg.half_gap_mm
        A[:, :3, 3] = d * A[:, :3, 2]
        A[:, 2, 3] += d  # Trans(z, d) R Trans(z, d)
        for _ in range(seg.n_subjoints):
            T = T @ A
            if seg.link_mass_g > 0:
                p = T[:, :3, 3] + 0.5 * seg.link_mm * T[:, :3, 2]
                V -= seg.link_mass_g * 1e-6 * (p @ g)
            T[:, :3, 3] += seg.link_mm * T[:, :3, 2]
    if arm.tip_mass_g > 0:
        p = T[:, :3, 3] + 0.5 * arm.tip_link_mm * T[:, :3, 2]
        V -= arm.tip_mass_g * 1e-6 * (p @ g)
    return V


def gravity_potential_Nmm(arm: UJointArm, theta: np.ndarray) -> float:
    """Gravity potential V = -sum m g . p of the moving links and tip mass (N*mm).

    Masses in g (* 1e-3 -> kg), gravity in mm/s^2 (* 1e-3 -> m/s^2), positions in mm.
    """
    return float(_potential_batch(arm, _as_theta(arm, theta)[None])[0])


def _has_gravity(arm: UJointArm) -> bool:
    return any(g != 0.0 for g in arm.gravity_mm_s2)


def gravity_torque(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Generalised gravity force Q = -dV/dtheta (2N,), N*mm per rad of sub-joint angle.

    Central differences of the potential (step :data:`GRAVITY_FD_STEP_RAD`).
    """
    t = _as_theta(arm, theta).ravel()
    n = t.size
    if not _has_gravity(arm):
        return np.zeros(n)
    E = np.eye(n) * GRAVITY_FD_STEP_RAD
    X = np.concatenate((t + E, t - E)).reshape(2 * n, -1, 2)
    V = _potential_batch(arm, X)
    return -(V[:n] - V[n:]) / (2.0 * GRAVITY_FD_STEP_RAD)


def gravity_hessian(arm: UJointArm, theta: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """d^2 V / dtheta^2 (2N x 2N, N*mm/rad^2) by the four-point stencil (the gravity stiffness,
    negative where gravity destabilises, e.g. an upright arm)."""
    t = _as_theta(arm, theta).ravel()
    return _fd_hessian(lambda X: _potential_batch(arm, X.reshape(X.shape[0], -1, 2)), t, h)


def _fd_hessian(potential: object, x: np.ndarray, h: float) -> np.ndarray:
    n = x.size
    pairs = [(j, k) for j in range(n) for k in range(j, n)]
    X = []
    for j, k in pairs:
        for sj, sk in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            y = x.copy()
            y[j] += sj * h
            y[k] += sk * h
            X.append(y)
    V = potential(np.array(X))  # type: ignore[operator]
    H = np.zeros((n, n))
    for p, (j, k) in enumerate(pairs):
        v = V[4 * p : 4 * p + 4]
        H[j, k] = H[k, j] = (v[0] - v[1] - v[2] + v[3]) / (4.0 * h * h)
    return H


def statics_angles(arm: UJointArm, theta_pre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Small-deflection equilibrium of the cable-held arm under gravity (N, 2) and cable tensions.

    The drives fix each cable's free length so that at ``theta_pre`` (the kinematic pose, from the
    cable lengths) every cable carries its pretension T0. Away from it, cable k stretches by
    J_k dtheta (J = :func:`cable_jacobian`) with stiffness k_k = EA / L_total, and the sub-joints
    have no elastic element of their own. Stationarity of
    V = sum_k [T0_k L_k(theta) + k_k/2 (L_k(theta) - L_k(theta_pre))^2] + V_gravity(theta):

        (J^T diag(k) J + K_g) dtheta = Q(theta_pre + dtheta) - J^T T0,
        K_g = sum_k T0_k d^2 L_k / dtheta^2   (geometric stiffness of the pretension,
                                               :func:`cable_jacobian_hessian`)

    with the cable lengths linearised at theta_pre and the gravity moment Q (:func:`gravity_torque`)
    taken at the sagged pose (quasi-Newton with the gravity stiffness of
    :func:`gravity_hessian`). A cable whose tension T0 + k J dtheta would go negative is slack and
    drops out (active set). Raises :class:`ModelError` if the equilibrium is not stable (the
    pretension or gravity buckles the arm, or slack cables leave a segment unheld).
    Returns (theta, tensions_N).
    """
    t0 = _as_theta(arm, theta_pre).ravel()
    J, L_hess = cable_jacobian_hessian(arm, t0.reshape(-1, 2))  # d^2 L_k / dtheta^2 per cable
    n = t0.size
    if _has_gravity(arm):
        H = gravity_hessian(arm, t0.reshape(-1, 2))

        def Q(x: np.ndarray) -> np.ndarray:
            return gravity_torque(arm, x.reshape(-1, 2))
    else:
        H = np.zeros((n, n))

        def Q(x: np.ndarray) -> np.ndarray:
            return np.zeros(n)

    x, tension = small_deflection(
        t0,
        J,
        arm.cable_stiffness_N_per_mm,
        arm.pretension_N,
        L_hess,
        np.zeros((n, n)),
        np.zeros(n),
        Q,
        H,
    )
    return x.reshape(-1, 2), tension


def small_deflection(
    x0: np.ndarray,
    J: np.ndarray,
    k: np.ndarray,
    T0: np.ndarray,
    L_hess: np.ndarray,
    K_rest: np.ndarray,
    f_rest: np.ndarray,
    Q: object,
    H: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve F(dx) = (J_a^T k_a J_a + K_g,a + K_rest) dx + J_a^T T0_a + f_rest - Q(x0 + dx) = 0.

    J_a, k_a, T0_a: the taut cables (tension T0 + k J dx >= 0; active set updated every
    iteration); K_g,a = sum over them of T0_k ``L_hess[k]`` (a slack cable loses its pretension
    and its geometric stiffness). Quasi-Newton with the fixed Jacobian K + H (H: the gravity
    Hessian at x0); raises :class:`ModelError` when K + H is not positive definite (no stable
    equilibrium).
    """
    active = np.ones(T0.shape, dtype=bool)  # every cable taut (a zero pretension too)
    dx = np.zeros_like(x0)
    n = x0.size
    # K, (K + H)^-1 and the pretension moment depend on the active set only: built (and the
    # stability checked) once per active set met
    built: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for _ in range(STATICS_MAX_ITER):
        key = active.tobytes()
        if key not in built:
            Ja, Ta, ka, La = J[active], T0[active], k[active], L_hess[active]
            Kg = (Ta @ La.reshape(Ta.size, n * n)).reshape(n, n)
            K = Ja.T @ (ka[:, None] * Ja) + Kg + K_rest
            A = K + H
            if np.linalg.eigvalsh(0.5 * (A + A.T)).min() <= 0.0:
                raise ModelError(
                    "statics: no stable equilibrium (slack cables, or pretension or "
                    "gravity buckling the arm)"
                )
            built[key] = (K, np.linalg.inv(A), Ja.T @ Ta + f_rest)
        K, A_inv, f0 = built[key]
        F = K @ dx + f0 - Q(x0 + dx)  # type: ignore[operator]
        step = A_inv @ F
        dx = dx - step
        new_active = (T0 + k * (J @ dx)) >= 0.0
        if (new_active == active).all() and float(np.abs(step).max()) < STATICS_TOL_RAD:
            break
        active = new_active
    else:
        raise ModelError("statics did not converge")
    tension = np.where(active, T0 + k * (J @ dx), 0.0)
    return x0 + dx, tension


def statics_inverse(
    arm: UJointArm,
    theta_target: np.ndarray,
    guess: np.ndarray | None = None,
    max_evals: int | None = None,
) -> np.ndarray:
    """theta_pre with :func:`statics_angles` (theta_pre) = ``theta_target`` (fixed point, N x 2).

    theta_pre <- theta_pre + (theta_target - statics(theta_pre)) from ``guess`` (default the
    target): the sag is small and smooth, so the iteration contracts by about |d sag/d theta|
    (~1e-2) per step. ``max_evals`` None: iterate to :data:`STATICS_TOL_RAD` (raises
    :class:`ModelError` if it does not get there); an integer: exactly that many statics
    evaluations (the control loop warm-starts from the last offset and takes one: its error is
    |d sag/d theta| times the change of the offset since the last tick).
    """
    target = _as_theta(arm, theta_target)
    pre = target.copy() if guess is None else np.array(guess, dtype=float)
    limit = STATICS_MAX_ITER if max_evals is None else max_evals
    for _ in range(limit):
        err = target - statics_angles(arm, pre)[0]
        pre = pre + err
        if max_evals is None and float(np.max(np.abs(err))) < STATICS_TOL_RAD:
            return pre
    if max_evals is None:
        raise ModelError("statics inverse did not converge (sag too large for small deflection)")
    return pre
