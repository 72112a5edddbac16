"""Cable lengths of the vertebra arm and their inverse (fuel-tank vertebra robot paper, eq. 3-5).

A joint's cable length eq. 3 with d the hole circle's DIAMETER (:func:`joint_cable_length`), its
shortening eq. 4 (:func:`joint_cable_shortening`), the whole cable's displacement eq. 5 through
every proximal joint (:func:`cable_displacements`), analytic Jacobian and Hessian in the bending
vector x, and the inverse of eq. 5 joint by joint (:func:`solve_joint`,
:func:`joints_from_displacements`).

Units: mm (pulled in), rad.
"""

from __future__ import annotations

import math

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.vertebra.forward import _psi_array, d1, d2, psi_from_x, s1
from cdcr_ctl.model.vertebra.params import (
    SOLVE_MAX_ITER,
    SOLVE_STEP_TOL_RAD,
    VertebraArm,
    VertebraJoint,
)


# =========================================================================== eq. 3-5
def joint_cable_length(
    theta: float,
    phi: float,
    beta: np.ndarray | float,
    hole_radius_mm: np.ndarray | float,
    joint: VertebraJoint,
) -> np.ndarray:
    """Cable length through one joint, eq. 3 (mm): n [H + l0 cos(theta/2n) - d sin(theta/2n)
    cos(phi - beta)] with d = 2 r (the hole-circle diameter; module docstring)."""
    n = joint.n_gaps
    u = theta / (2.0 * n)
    d = 2.0 * np.asarray(hole_radius_mm, dtype=float)
    return n * (
        joint.hole_length_mm
        + joint.gap_mm * math.cos(u)
        - d * math.sin(u) * np.cos(phi - np.asarray(beta, dtype=float))
    )


def joint_cable_shortening(
    theta: float,
    phi: float,
    beta: np.ndarray | float,
    hole_radius_mm: np.ndarray | float,
    joint: VertebraJoint,
) -> np.ndarray:
    """Eq. 4: Delta L = n {l0 - [l0 cos(theta/2n) - d sin(theta/2n) cos(phi - beta)]} (mm, > 0
    when the cable is pulled in)."""
    return joint.n_gaps * (joint.gap_mm + joint.hole_length_mm) - joint_cable_length(
        theta, phi, beta, hole_radius_mm, joint
    )


def _joint_length_x(
    x: np.ndarray, beta: np.ndarray, r: np.ndarray, joint: VertebraJoint
) -> tuple[np.ndarray, np.ndarray]:
    """(L (K,), dL/dx (K, 2)) of eq. 3 in the bending vector x (smooth through x = 0).

    With u = theta/2n and x_beta = x . (cos beta, sin beta) = theta cos(phi - beta):
    L = n H + n l0 cos u - r s1(u) x_beta, and (s1, cos u even in theta)
    dL/dx = -(l0 / 4n) s1(u) x - (r / 4n^2) d1(u) x_beta x - r s1(u) (cos beta, sin beta).
    """
    n = joint.n_gaps
    theta = math.hypot(float(x[0]), float(x[1]))
    u = theta / (2.0 * n)
    e = np.column_stack((np.cos(beta), np.sin(beta)))
    xb = e @ x
    su = s1(u)
    L = n * joint.hole_length_mm + n * joint.gap_mm * math.cos(u) - r * su * xb
    dL = (
        -(joint.gap_mm / (4.0 * n)) * su * x[None, :]
        - (r * d1(u) * xb / (4.0 * n * n))[:, None] * x[None, :]
        - (r * su)[:, None] * e
    )
    return L, dL


def cable_path_lengths(arm: VertebraArm, psi: np.ndarray) -> np.ndarray:
    """Per cable, its length through every joint it passes (mm), eq. 3 summed as in eq. 5."""
    p = _psi_array(psi, arm.n_joints)
    L = np.zeros(arm.n_cables)
    for i, j in enumerate(arm.joints):
        through = arm.anchor >= i
        L[through] += joint_cable_length(
            p[i, 0], p[i, 1], arm.betas[through], arm.radii[through], j
        )
    return L


def straight_path_mm(arm: VertebraArm) -> np.ndarray:
    """Per cable, its path length at the straight pose, sum of n (l0 + H) over its joints (mm)."""
    return arm.straight_path.copy()


def cable_displacements(arm: VertebraArm, psi: np.ndarray) -> np.ndarray:
    """Eq. 5: each cable's total shortening, the sum of eq. 4 over the joints it passes (mm pulled
    in). A distal joint's cables change with every proximal joint's pose (the coupling)."""
    return arm.straight_path - cable_path_lengths(arm, psi)


def cable_jacobian_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    """d(path length)/d(bending vectors) (C x 2N, mm/rad), columns (x_1, y_1, x_2, ...)."""
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    J = np.zeros((arm.n_cables, 2 * arm.n_joints))
    for i, j in enumerate(arm.joints):
        through = np.nonzero(arm.anchor >= i)[0]
        _, dL = _joint_length_x(xs[i], arm.betas[through], arm.radii[through], j)
        J[np.ix_(through, [2 * i, 2 * i + 1])] = dL
    return J


def _joint_length_hess_x(
    x: np.ndarray, beta: np.ndarray, r: np.ndarray, joint: VertebraJoint
) -> np.ndarray:
    """d^2 L / dx^2 (K, 2, 2) of eq. 3 in the bending vector (mm/rad^2), the derivative of
    :func:`_joint_length_x`'s dL/dx. With ds1/dx = d1(u) x / 4n^2 and dd1/dx = d2(u) x / 4n^2:

        -(l0/4n) s1 I - (l0 d1/16n^3) x x^T - (r d1 x_beta/4n^2) I
        - (r d1/4n^2) (x e^T + e x^T) - (r x_beta d2/16n^4) x x^T,   e = (cos beta, sin beta).
    """
    n = joint.n_gaps
    xv = np.asarray(x, dtype=float)
    theta = math.hypot(float(xv[0]), float(xv[1]))
    u = theta / (2.0 * n)
    su, du, ddu = s1(u), d1(u), d2(u)
    e = np.column_stack((np.cos(beta), np.sin(beta)))
    xb = e @ xv
    r = np.asarray(r, dtype=float)
    xx = np.outer(xv, xv)
    eye = np.eye(2)
    l0 = joint.gap_mm
    common = -(l0 / (4.0 * n)) * su * eye - (l0 * du / (16.0 * n**3)) * xx
    xe = xv[None, :, None] * e[:, None, :]  # x e^T per cable
    return (
        common[None]
        - (r * du * xb / (4.0 * n * n))[:, None, None] * eye[None]
        - (r * du / (4.0 * n * n))[:, None, None] * (xe + xe.transpose(0, 2, 1))
        - (r * xb * ddu / (16.0 * n**4))[:, None, None] * xx[None]
    )


def cable_hessian_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    """d^2(path length)/d(bending vectors)^2 (C, 2N, 2N, mm/rad^2), analytic
    (:func:`_joint_length_hess_x`); block diagonal per joint (a joint's share of a cable's length
    depends on that joint's bending vector only)."""
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    Hs = np.zeros((arm.n_cables, 2 * arm.n_joints, 2 * arm.n_joints))
    for i, j in enumerate(arm.joints):
        through = np.nonzero(arm.anchor >= i)[0]
        Hs[through, 2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = _joint_length_hess_x(
            xs[i], arm.betas[through], arm.radii[through], j
        )
    return Hs


def _cable_jacobian_and_hessian(arm: VertebraArm, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(:func:`cable_jacobian_x`, :func:`cable_hessian_x`) at ``x`` in one pass over the joints
    (the formulas of :func:`_joint_length_x` and :func:`_joint_length_hess_x`, entry by entry)."""
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    n2 = 2 * arm.n_joints
    J = np.zeros((arm.n_cables, n2))
    Hs = np.zeros((arm.n_cables, n2, n2))
    for i, j in enumerate(arm.joints):
        idx, e, r = arm.through[i]
        n = j.n_gaps
        x0, x1 = float(xs[i, 0]), float(xs[i, 1])
        u = math.hypot(x0, x1) / (2.0 * n)
        su, du, ddu = s1(u), d1(u), d2(u)
        e0, e1 = e[:, 0], e[:, 1]
        xb = e0 * x0 + e1 * x1
        g = -(j.gap_mm / (4.0 * n)) * su
        a = r * du * xb / (4.0 * n * n)
        rs = r * su
        J[idx, 2 * i] = (g - a) * x0 - rs * e0
        J[idx, 2 * i + 1] = (g - a) * x1 - rs * e1
        # g I - (l0 d1/16n^3) x x^T - a I - b (x e^T + e x^T) - c x x^T
        b = r * du / (4.0 * n * n)
        cxx = (j.gap_mm * du / (16.0 * n**3)) + r * xb * ddu / (16.0 * n**4)
        diag = g - a
        Hs[idx, 2 * i, 2 * i] = diag - 2.0 * b * x0 * e0 - cxx * x0 * x0
        Hs[idx, 2 * i + 1, 2 * i + 1] = diag - 2.0 * b * x1 * e1 - cxx * x1 * x1
        off = -b * (x0 * e1 + x1 * e0) - cxx * x0 * x1
        Hs[idx, 2 * i, 2 * i + 1] = off
        Hs[idx, 2 * i + 1, 2 * i] = off
    return J, Hs


def _path_lengths_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    """Per cable, its path length (mm) at the bending vectors ``x`` (eq. 3 summed as in eq. 5,
    the L of :func:`_joint_length_x`)."""
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    L = np.zeros(arm.n_cables)
    for i, j in enumerate(arm.joints):
        idx, e, r = arm.through[i]
        x0, x1 = float(xs[i, 0]), float(xs[i, 1])
        n = j.n_gaps
        u = math.hypot(x0, x1) / (2.0 * n)
        L[idx] += (
            n * j.hole_length_mm
            + n * j.gap_mm * math.cos(u)
            - r * s1(u) * (e[:, 0] * x0 + e[:, 1] * x1)
        )
    return L


def x_from_psi(psi: np.ndarray) -> np.ndarray:
    """(N, 2) rows (theta, phi) -> (N, 2) bending vectors."""
    p = np.asarray(psi, dtype=float)
    return np.column_stack((p[:, 0] * np.cos(p[:, 1]), p[:, 0] * np.sin(p[:, 1])))


def psi_from_xs(x: np.ndarray, phi_if_straight: np.ndarray | None = None) -> np.ndarray:
    """(N, 2) bending vectors -> rows (theta, phi); ``phi_if_straight`` per joint at theta = 0."""
    xs = np.asarray(x, dtype=float).reshape(-1, 2)
    out = np.zeros_like(xs)
    for i, xi in enumerate(xs):
        fallback = 0.0 if phi_if_straight is None else float(phi_if_straight[i])
        out[i] = psi_from_x(xi, fallback)
    return out


def solve_joint(
    lengths_mm: np.ndarray,
    beta: np.ndarray,
    r: np.ndarray,
    joint: VertebraJoint,
    guess: np.ndarray | None = None,
) -> np.ndarray:
    """Bending vector of one joint from its cables' lengths through it (Gauss-Newton on eq. 3,
    the L and dL/dx of :func:`_joint_length_x`, in scalar arithmetic: a joint has a handful of
    cables).

    Least squares (2x2 normal equations) when the lengths are inconsistent. Raises
    :class:`ModelError` when it does not converge (lengths out of reach) or the cables cannot
    fix the bend (all collinear with the centre).
    """
    ld = [float(v) for v in np.asarray(lengths_mm, dtype=float)]
    cables = [
        (math.cos(float(b)), math.sin(float(b)), float(rr), li)
        for b, rr, li in zip(
            np.asarray(beta, dtype=float), np.asarray(r, dtype=float), ld, strict=True
        )
    ]
    n = joint.n_gaps
    base = n * joint.hole_length_mm
    l0 = joint.gap_mm
    x0, x1 = (0.0, 0.0) if guess is None else (float(guess[0]), float(guess[1]))
    for _ in range(SOLVE_MAX_ITER):
        u = math.hypot(x0, x1) / (2.0 * n)
        su, du = s1(u), d1(u)
        common = base + n * l0 * math.cos(u)
        ga = -(l0 / (4.0 * n)) * su
        # normal equations: (dL^T dL) step = dL^T (ld - L)
        a00 = a01 = a11 = b0 = b1 = 0.0
        for ec, es, rr, li in cables:
            xb = ec * x0 + es * x1
            res = li - (common - rr * su * xb)
            f = ga - rr * du * xb / (4.0 * n * n)
            j0 = f * x0 - rr * su * ec
            j1 = f * x1 - rr * su * es
            a00 += j0 * j0
            a01 += j0 * j1
            a11 += j1 * j1
            b0 += j0 * res
            b1 += j1 * res
        det = a00 * a11 - a01 * a01
        if not det > 1e-12 * (a00 * a11 + 1e-300):
            raise ModelError(f"joint {joint.name}: its cables do not fix the bend here")
        s0 = (a11 * b0 - a01 * b1) / det
        s1_ = (a00 * b1 - a01 * b0) / det
        big = max(abs(s0), abs(s1_))
        if big > 0.5:
            s0, s1_ = s0 * 0.5 / big, s1_ * 0.5 / big
        x0, x1 = x0 + s0, x1 + s1_
        if big < SOLVE_STEP_TOL_RAD:
            return np.array([x0, x1])
    raise ModelError(f"joint {joint.name}: cable lengths {ld} mm out of reach")


def joints_from_displacements(
    arm: VertebraArm, q_mm: np.ndarray, guess_x: np.ndarray | None = None
) -> np.ndarray:
    """Inverse of eq. 5: bending vectors (N, 2) from cable displacements (mm pulled in).

    Joint 1 from its own cables, then its share of every distal cable is removed and joint 2 is
    solved, and so on outwards (the coupling runs one way: distal cables pass proximal joints).
    """
    L = arm.straight_path - np.asarray(q_mm, dtype=float)
    xs = np.zeros((arm.n_joints, 2))
    used = np.zeros(arm.n_cables)
    for i, j in enumerate(arm.joints):
        own = arm.own_cables[i]
        g = None if guess_x is None else np.asarray(guess_x, dtype=float).reshape(-1, 2)[i]
        xs[i] = solve_joint(L[own] - used[own], arm.betas[own], arm.radii[own], j, g)
        distal = arm.anchor > i
        if distal.any():
            used[distal] += _joint_length_x(xs[i], arm.betas[distal], arm.radii[distal], j)[0]
    return xs
