"""Cable lengths of the universal-joint arm and their inverse (Yang et al. 2022, eq. 4-13, 15).

Sub-joint cable length eq. 4 (:func:`subjoint_cable_length` and its gradient), the segment's
equal-angle sub-joints with the first-axis sign of eq. 5-6 (:func:`segment_cable_lengths`,
:func:`subjoint_angles`), the Newton solve of eq. 7-10 (:func:`solve_segment_angles`), whole
cable paths eq. 11-12 (:func:`cable_path_lengths`, :func:`angles_from_path_lengths`), the
linearised angle error of eq. 13 / 15 (:func:`linearised_angle_error`), and the analytic cable
Jacobian and Hessian the statics use (fast paths: :func:`cable_jacobian_hessian`).

Units: mm, rad. ``q`` is mm pulled in at the drive (q = -Delta l of the paper).
"""

from __future__ import annotations

import math

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.ujoint.params import NEWTON_MAX_ITER, NEWTON_STEP_TOL_RAD, HoleSet, UJointArm


# =========================================================================== rotations
def rot_x(a: float) -> np.ndarray:
    """Rotation about x by ``a`` (rad), 3x3."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(b: float) -> np.ndarray:
    """Rotation about y by ``b`` (rad), 3x3."""
    c, s = math.cos(b), math.sin(b)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _homog(R: np.ndarray, p: np.ndarray | tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def _trans_z(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z
    return T


def _rotation_rows(a: float, b: float, order: int) -> np.ndarray:
    """Rx(a) Ry(b) (eq. 4's sub-joint rotation) and its partial derivatives, each flattened row by
    row, (1, 3 or 6, 9): R; with order >= 1 also R_a, R_b; with order 2 also R_aa, R_ab, R_bb
    (a, b in rad)."""
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    rows = [[cb, 0.0, sb, sa * sb, ca, -sa * cb, -ca * sb, sa, ca * cb]]
    if order >= 1:
        rows.append([0.0, 0.0, 0.0, ca * sb, -sa, -ca * cb, sa * sb, ca, -sa * cb])
        rows.append([-sb, 0.0, cb, sa * cb, 0.0, sa * sb, -ca * cb, 0.0, -ca * sb])
    if order >= 2:
        rows.append([0.0, 0.0, 0.0, -sa * sb, -ca, sa * cb, ca * sb, -sa, -ca * cb])
        rows.append([0.0, 0.0, 0.0, ca * cb, 0.0, ca * sb, sa * cb, 0.0, sa * sb])
        rows.append([-cb, 0.0, -sb, -sa * sb, 0.0, sa * cb, ca * sb, 0.0, -ca * cb])
    return np.array(rows)


def _hole_lengths(holes: HoleSet, a: float, b: float) -> np.ndarray:
    """Eq. 5 for the cables of ``holes``, every sub-joint at the physical angles (a, b): the
    lengths (K,) across the segment, m f_i (mm); see :func:`_hole_terms`."""
    S = _rotation_rows(a, b, 0) @ holes.outer
    return holes.m * np.sqrt(holes.norms - 2.0 * S[0])


def _hole_terms(
    holes: HoleSet, a: float, b: float, second: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 5 for the cables of ``holes`` with every sub-joint at the physical angles (a, b):
    (f (K,), g (2, K), h (3, K)), f = m f_i the length across the segment (mm), g its
    derivatives along a and b (mm/rad, eq. 9) and, with ``second``, h the second derivatives
    aa, ab, bb (mm/rad^2; else h is empty, (0, K)).

    Eq. 4 as the bilinear form of :class:`HoleSet`: with s = l^T R u and its derivatives
    s_x = l^T R_x u (one product ``outer @ vec(R_x)``), f_i^2 = ``norms`` - 2 s, so
    f_x = -s_x / f_i and f_xy = -(s_xy + f_x f_y) / f_i. f_i >= 2 d cos(angle) - 2 rho > 0 for a
    real joint, so nothing divides by 0.
    """
    S = _rotation_rows(a, b, 2 if second else 1) @ holes.outer  # s, s_a, s_b(, s_aa, s_ab, s_bb)
    f = np.sqrt(holes.norms - 2.0 * S[0])
    g = -S[1:3] / f  # (2, K)
    h = -(S[3:6] + g[_HESS_I] * g[_HESS_J]) / f if second else S[3:]  # aa, ab, bb
    m = holes.m
    return m * f, m * g, m * h


#: Rows of the (aa, ab, bb) second derivatives: index pairs into the first derivatives (a, b).
_HESS_I = np.array([0, 0, 1])
_HESS_J = np.array([0, 1, 1])


# =========================================================================== eq. 4-6
def subjoint_cable_length(
    psi_I: float, psi_J: float, beta: np.ndarray | float, rho: np.ndarray | float, d: float
) -> np.ndarray:
    """Straight cable length between the hole pair of one sub-joint (mm), eq. 4 as printed.

    Holes at (rho cos beta, rho sin beta, -d) in the joint-centre frame (disk D1) and at
    Rot(x, psi_I) Rot(y, psi_J) (rho cos beta, rho sin beta, d) (disk D2); the three components
    below are those of the difference, exactly eq. 4's three squared terms. ``psi_I`` is the
    physical rotation about the frame's x axis (see module docstring on eq. 6). At psi = 0: 2 d.
    """
    b = np.asarray(beta, dtype=float)
    r = np.asarray(rho, dtype=float)
    cI, sI, cJ, sJ = math.cos(psi_I), math.sin(psi_I), math.cos(psi_J), math.sin(psi_J)
    cb, sb = np.cos(b), np.sin(b)
    v1 = d * sJ + r * cJ * cb - r * cb
    v2 = r * cb * sI * sJ + r * cI * sb - d * sI * cJ - r * sb
    v3 = r * sI * sb - r * cb * cI * sJ + d * cI * cJ + d
    return np.sqrt(v1 * v1 + v2 * v2 + v3 * v3)


def subjoint_cable_length_grad(
    psi_I: float, psi_J: float, beta: np.ndarray | float, rho: np.ndarray | float, d: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(f, df/dpsi_I, df/dpsi_J) of eq. 4 (mm, mm/rad), from the component derivatives.

    f = |v| is never 0 for a real joint (f >= 2 d cos(psi) - 2 rho), so the gradient v.dv / f is
    finite everywhere, including the straight pose where it is (rho sin beta, -rho cos beta).
    """
    b = np.asarray(beta, dtype=float)
    r = np.asarray(rho, dtype=float)
    cI, sI, cJ, sJ = math.cos(psi_I), math.sin(psi_I), math.cos(psi_J), math.sin(psi_J)
    cb, sb = np.cos(b), np.sin(b)
    v1 = d * sJ + r * cJ * cb - r * cb
    v2 = r * cb * sI * sJ + r * cI * sb - d * sI * cJ - r * sb
    v3 = r * sI * sb - r * cb * cI * sJ + d * cI * cJ + d
    f = np.sqrt(v1 * v1 + v2 * v2 + v3 * v3)
    # d/dpsi_I (v1 has no psi_I)
    v2a = r * cb * cI * sJ - r * sI * sb - d * cI * cJ
    v3a = r * cI * sb + r * cb * sI * sJ - d * sI * cJ
    # d/dpsi_J
    v1b = d * cJ - r * sJ * cb
    v2b = r * cb * sI * cJ + d * sI * sJ
    v3b = -r * cb * cI * cJ - d * cI * sJ
    return f, (v2 * v2a + v3 * v3a) / f, (v1 * v1b + v2 * v2b + v3 * v3b) / f


def first_axis_signs(m: int) -> np.ndarray:
    """Direction of the first axis xi_{n,i,I} along the segment x axis, (-1)^(i+1), i = 1..m."""
    return np.array([1.0 if i % 2 == 1 else -1.0 for i in range(1, m + 1)])


def subjoint_angles(theta_a: float, theta_b: float, m: int) -> np.ndarray:
    """(m, 2) D-H-local sub-joint angles (psi_{n,i,I}, psi_{n,i,J}) of eq. 6 (rad).

    theta_{2n-1} = (-1)^(i+1) psi_{n,i,I} and theta_{2n} = psi_{n,i,J} for i = 1..m.
    """
    s = first_axis_signs(m)
    return np.column_stack((s * theta_a, np.full(m, float(theta_b))))


def _physical_angles(theta_a: float, theta_b: float, m: int) -> np.ndarray:
    """(m, 2) physical rotations of the sub-joints about the segment x and y axes: eq. 6's D-H
    angles times the direction of their first axis, (-1)^(i+1) psi_{n,i,I} = theta_{2n-1}."""
    psi = subjoint_angles(theta_a, theta_b, m)
    return np.column_stack((first_axis_signs(m) * psi[:, 0], psi[:, 1]))


def segment_cable_lengths(
    theta_a: float,
    theta_b: float,
    beta: np.ndarray | float,
    rho: np.ndarray | float,
    d: float,
    m: int,
) -> np.ndarray:
    """Length of each cable across the m sub-joints of one segment (mm), eq. 5 with eq. 6.

    f_{n,k} = sum_i f_{n,i,k}: each sub-joint's D-H angles (eq. 6) are turned back into the
    physical rotation about the segment x axis, sign_i * psi_{n,i,I} = theta_{2n-1}, before eq. 4.
    All m sub-joints then turn alike (equal-angle linkage): the sum is m times the first term.
    """
    a, b = _physical_angles(theta_a, theta_b, m)[0]
    holes = HoleSet.from_holes(np.zeros(0, dtype=int), beta, rho, d, m)
    return _hole_lengths(holes, float(a), float(b))


def segment_cable_jacobian(
    theta_a: float,
    theta_b: float,
    beta: np.ndarray | float,
    rho: np.ndarray | float,
    d: float,
    m: int,
) -> tuple[np.ndarray, np.ndarray]:
    """(f, J_d) of one segment: lengths (K,) and the K x 2 matrix df_k/d(theta_{2n-1}, theta_{2n}).

    J_d is eq. 9 (NOTES: the printed eq. 9 is garbled; this is the 3 x 2 matrix of partials).
    Every sub-joint turns by the same physical angles, d(sign_i psi_I)/d theta_{2n-1} =
    sign_i^2 = 1, so J_d is the eq. 4 gradient summed over the m sub-joints.
    """
    a, b = _physical_angles(theta_a, theta_b, m)[0]
    holes = HoleSet.from_holes(np.zeros(0, dtype=int), beta, rho, d, m)
    f, g, _ = _hole_terms(holes, float(a), float(b))
    return f, g.T


# =========================================================================== eq. 7-12
def _as_theta(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    t = np.asarray(theta, dtype=float)
    if t.shape != (arm.n_segments, 2):
        raise ModelError(f"joint angles must have shape ({arm.n_segments}, 2), got {t.shape}")
    return t


def cable_path_lengths(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Per cable, its length across every joint gap it passes (mm), eq. 11 without the -2nMd.

    Cable k anchored in segment n_k: sum over i <= n_k of f_{i,k}(theta_{2i-1}, theta_{2i}).
    The rigid link tubes and the drive box add constant lengths and are left out.
    Every sub-joint of segment i turns by the physical angles (theta_{2i-1}, theta_{2i}) (eq. 6,
    :func:`segment_cable_lengths`), so eq. 5 is evaluated once per segment on its
    :attr:`UJointArm.hole_sets`.
    """
    t = _as_theta(arm, theta)
    L = np.zeros(arm.n_cables)
    for i, holes in enumerate(arm.hole_sets):
        L[holes.passing.index] += _hole_lengths(holes.passing, t[i, 0], t[i, 1])
    return L


def cable_displacements(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Ideal inverse kinematics: cable pulled in at the drive (mm) for joint angles ``theta``.

    q_k = -Delta l_k = sum_i 2 M_i d_i - sum_i f_{i,k}(theta_i), eq. 11 with this project's sign.
    """
    return arm.straight_path_mm - cable_path_lengths(arm, theta)


def cable_jacobian(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """d(path length)/d(theta) (C x 2N, mm/rad), columns (theta_1, theta_2, ..., theta_2N).

    Block (cable k, segment i) is the eq. 9 row of cable k in segment i when k passes i, else 0.
    """
    t = _as_theta(arm, theta)
    J = np.zeros((arm.n_cables, 2 * arm.n_segments))
    for i, holes in enumerate(arm.hole_sets):
        hs = holes.passing
        _, g, _ = _hole_terms(hs, t[i, 0], t[i, 1])
        J[hs.index, 2 * i] = g[0]
        J[hs.index, 2 * i + 1] = g[1]
    return J


def cable_jacobian_hessian(arm: UJointArm, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J, H): :func:`cable_jacobian` and d^2 (path length) / d theta^2 per cable
    (C x 2N x 2N, mm/rad^2; block diagonal: a segment's angles only change the cable's chords in
    that segment), analytically from eq. 4 (:func:`_hole_terms`)."""
    t = _as_theta(arm, theta)
    C, n = arm.n_cables, 2 * arm.n_segments
    J = np.zeros((C, n))
    H = np.zeros((C, n, n))
    for i, holes in enumerate(arm.hole_sets):
        hs = holes.passing
        _, g, h = _hole_terms(hs, t[i, 0], t[i, 1], second=True)
        J[hs.index, 2 * i] = g[0]
        J[hs.index, 2 * i + 1] = g[1]
        H[hs.index, 2 * i, 2 * i] = h[0]
        H[hs.index, 2 * i, 2 * i + 1] = h[1]
        H[hs.index, 2 * i + 1, 2 * i] = h[1]
        H[hs.index, 2 * i + 1, 2 * i + 1] = h[2]
    return J, H


def solve_segment_angles(
    lengths_mm: np.ndarray,
    beta: np.ndarray,
    rho: np.ndarray,
    d: float,
    m: int,
    guess: np.ndarray | None = None,
) -> np.ndarray:
    """Segment angles (theta_{2n-1}, theta_{2n}) from its cables' lengths (eq. 7-10, Fig. 8).

    Newton / Gauss-Newton: theta <- theta + J_d^+ (l_d - f(theta)) with the pseudo-inverse of the
    3 x 2 J_d (eq. 10) until the step is below :data:`NEWTON_STEP_TOL_RAD`. With 3 cables for 2
    unknowns, inconsistent lengths (stretched cables) give the least-squares angles.
    Raises :class:`ModelError` when the iteration does not converge (lengths out of reach).
    """
    holes = HoleSet.from_holes(np.zeros(0, dtype=int), beta, rho, d, m)
    return _solve_holes(holes, np.asarray(lengths_mm, dtype=float), guess)


def _solve_holes(holes: HoleSet, ld: np.ndarray, guess: np.ndarray | None) -> np.ndarray:
    """:func:`solve_segment_angles` on prepared holes. The step J_d^+ (l_d - f) is solved from
    the 2 x 2 normal equations (J_d^T J_d) step = J_d^T (l_d - f), which is the pseudo-inverse
    for a J_d of full column rank (holes not collinear with the centre, checked by
    :class:`UJointArm`); a numerically singular J_d falls back to :func:`numpy.linalg.pinv`."""
    a, b = (0.0, 0.0) if guess is None else (float(guess[0]), float(guess[1]))
    for _ in range(NEWTON_MAX_ITER):
        f, g, _ = _hole_terms(holes, a, b)
        r = ld - f
        (A00, A01), (A10, A11) = (g @ g.T).tolist()
        y0, y1 = (g @ r).tolist()
        det = A00 * A11 - A01 * A10
        if det > 1e-12 * A00 * A11:
            da = (A11 * y0 - A01 * y1) / det
            db = (A00 * y1 - A10 * y0) / det
        else:
            da, db = (float(x) for x in np.linalg.pinv(g.T) @ r)
        # the equal-angle joints reach at most ~pi/2 per sub-joint; damp wild first steps
        big = max(abs(da), abs(db))
        if big > 0.3:
            da, db = da * 0.3 / big, db * 0.3 / big
            big = 0.3
        a, b = a + da, b + db
        if big < NEWTON_STEP_TOL_RAD:
            return np.array([a, b])
    raise ModelError(
        f"eq. 10 iteration did not converge for lengths {ld.tolist()} mm (last angles {[a, b]} rad)"
    )


def angles_from_path_lengths(
    arm: UJointArm,
    lengths_mm: np.ndarray,
    guess: np.ndarray | None = None,
    offsets_rad: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Whole-arm joint angles from the cable path lengths, segment by segment (eq. 11-12, Fig. 9).

    Segment 1 from its own cables; the part of every distal cable inside segment 1 (the coupling
    length l_c) is computed at segment 1's angles and subtracted (eq. 12: l_d = l - l_c), and so on
    outwards. ``offsets_rad`` (N, 2) are added to each segment's solved angles before they are used
    for the coupling of distal cables (the deformation of eq. 14: the distal cables run through
    the deformed proximal segment). Returns (theta_kin, theta) with theta = theta_kin + offsets.
    """
    L = np.asarray(lengths_mm, dtype=float)
    N = arm.n_segments
    kin = np.zeros((N, 2))
    out = np.zeros((N, 2))
    used = np.zeros(arm.n_cables)  # coupling length consumed in proximal segments
    for n, holes in enumerate(arm.hole_sets):
        own = holes.own.index
        g = None if guess is None else np.asarray(guess, dtype=float)[n]
        kin[n] = _solve_holes(holes.own, L[own] - used[own], g)
        out[n] = kin[n] + (0.0 if offsets_rad is None else np.asarray(offsets_rad)[n])
        distal = holes.through
        if distal.index.size:
            used[distal.index] += _hole_lengths(distal, out[n, 0], out[n, 1])
    return kin, out


def angles_from_displacements(
    arm: UJointArm, q_mm: np.ndarray, guess: np.ndarray | None = None
) -> np.ndarray:
    """Ideal forward kinematics: joint angles (N, 2) from cable displacements pulled in (mm)."""
    return angles_from_path_lengths(arm, arm.straight_path_mm - np.asarray(q_mm), guess)[1]


def linearised_angle_error(
    arm: UJointArm, theta: np.ndarray, dq_out_mm: np.ndarray, dtheta_de: np.ndarray | None = None
) -> np.ndarray:
    """First-order joint-angle error (N, 2) from cable-output errors, eq. 13 and 15 (rad).

    Segment by segment: Delta theta_n = J_dn^+ (-dq_own - sum_{i<n} J_{own,i} Delta theta_i),
    where Delta theta_i of a proximal segment includes its deformation ``dtheta_de`` (eq. 15's
    J_dn Delta theta_de,n term). For a single segment this is eq. 13, Delta theta_h = J_d^+ l_h
    (l_h = -dq: a cable that lags while pulled in is longer in the arm).
    """
    J = cable_jacobian(arm, theta)
    dq = np.asarray(dq_out_mm, dtype=float)
    de = np.zeros((arm.n_segments, 2)) if dtheta_de is None else np.asarray(dtheta_de)
    out = np.zeros((arm.n_segments, 2))
    for n in range(arm.n_segments):
        own = arm.own_cables[n]
        rhs = -dq[own]
        for i in range(n):
            rhs = rhs - J[np.ix_(own, [2 * i, 2 * i + 1])] @ out[i]
        out[n] = np.linalg.pinv(J[np.ix_(own, [2 * n, 2 * n + 1])]) @ rhs + de[n]
    return out
