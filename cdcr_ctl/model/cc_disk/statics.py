"""Virtual-work statics of the whole robot (Qi et al. 2023 eq. 7-15), reference implementation.

Virtual work (eq. 7, 9) for all segments at once, with psi stacked (theta_1, phi_1, ...):

    J_qpsi^T tau = grad U - Q_ext,     U = sum EI_i theta_i^2 / (2 l_i)   (eq. 8)

tau the cable tensions (N) acting at the anchors (the tension that bends the robot), J_qpsi the
multi-segment cable Jacobian (:func:`cdcr_ctl.model.cc_disk.routing.cable_jacobian`), Q_ext the
generalised external forces (disk weights here). Units: N, N*mm, rad.

Moment-vector form (handles the theta = 0 rank loss, NOTES eq. 10): in bending-vector
coordinates x_i = theta_i (cos phi_i, sin phi_i), q_k = sum_i r_k e_k . x_i with
e_k = (cos gamma_k, sin gamma_k), so the equations of segment i read

    sum_{k: a(k) >= i} T_k Fbar_ki r_k e_k = m_i := (EI_i/l_i) x_i - Q_x,i        (2-vectors)

which is the phi row of eq. 9 divided by theta_i (finite at theta = 0). Fbar_ki = 1 without
friction; with disk friction it is the mean of the span tensions of cable k in segment i over its
anchor tension (the virtual work of a cable whose tension varies span by span is
sum_spans T_span dq_span; each span of segment i takes 1/n_i of the segment's shortening).

Coupling (eq. 11-15): the cables anchored distal to segment i cross it, so they load it with
c_i = sum_{k: a(k) > i} T_k Fbar_ki r_k e_k. Without friction this is m_{i+1}, the demand of
segment i+1; without weights m_{i+1} = M_{i+1} u_{i+1}, u = (cos phi, sin phi),
M_{i+1} = EI_{i+1} theta_{i+1} / l_{i+1} (eq. 12): the moment of segment i+1 in ITS bending plane.
In (theta_i, phi_i) coordinates it is M [cos(phi_{i+1} - phi_i), theta_i sin(phi_{i+1} - phi_i)];
the printed [M, 0] holds only for one common plane (NOTES). Virtual work gives it the sign that
LOWERS the proximal cables' load, J_ii^T tau_i = grad U_i - c_i (a distal cable pulled alone bends
a uniform robot at constant curvature; tested). Eq. 14-15 as printed, with M_c = -EI theta / l and
J^T tau~ = J^T tau - M_c, would raise it instead: we follow virtual work.
:func:`coupling_force` is this term; the tests show it equals the all-cables form.

Pretension (eq. 10): for 3 cables at 120 deg the null space of the 2x3 block is the pretension
direction [1 1 1]; the printed projector has the wrong shape (NOTES). Its multiplier is chosen so
that every cable keeps at least its pretension and the least-tensioned one exactly its pretension:
minimise sum T over T >= T0 subject to the two equations (a 2-row linear programme whose optimum
has at most two cables above pretension; :func:`pretension_tensions` enumerates the pairs).
With disk friction the rule is applied to each cable's mean tension along its anchor segment
(M_k = T_k Fbar_k,a, the quantity the moment balance and the stretch inside that segment see),
and T_k = M_k / Fbar_k,a. Then a friction reversal at a fixed pose leaves M, hence the pose and the
cable material inside the robot, unchanged: the inverse of the forward model's stick phase.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.optimize import linprog

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.kinematics import point_jacobian, psi_to_x
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams
from cdcr_ctl.model.cc_disk.routing import cable_jacobian, wrap_angles
from cdcr_ctl.model.shared.friction import propagate

#: grams * mm/s^2 -> N
G_MM_S2_TO_N = 1e-6


def elastic_gradient(psi: np.ndarray, params: RobotParams) -> np.ndarray:
    """grad U w.r.t. psi (2S,), N*mm/rad, eq. 8: dU/dtheta_i = EI_i theta_i / l_i, dU/dphi_i = 0."""
    psi = np.asarray(psi, dtype=float).reshape(-1, 2)
    g = np.zeros(2 * psi.shape[0])
    for i, seg in enumerate(params.segments):
        g[2 * i] = seg.EI_Nmm2 * psi[i, 0] / seg.length_mm
    return g


def gravity_force(psi: np.ndarray, params: RobotParams, coords: str = "psi") -> np.ndarray:
    """Generalised force of the disk weights (2S,), sum_m J_m^T m_m g (N*mm per rad).

    Disk m of segment i (mass from the config, each of the n_i disks after the segment's base)
    sits at arc fraction m/n_i; J_m its linear Jacobian in the base frame
    (:func:`cdcr_ctl.model.cc_disk.kinematics.point_jacobian`); g the gravity vector in the base
    frame. ``coords="x"`` gives the force conjugate to the bending vectors (phi components / theta).
    """
    psi = np.asarray(psi, dtype=float).reshape(-1, 2)
    g = np.asarray(params.gravity_mm_s2, dtype=float) * G_MM_S2_TO_N
    lengths = params.lengths_mm
    Q = np.zeros(2 * psi.shape[0])
    for i, seg in enumerate(params.segments):
        if seg.disk_mass_g == 0.0:
            continue
        for m in range(1, seg.n_disks + 1):
            _, Jv, _ = point_jacobian(psi, lengths, i, m / seg.n_disks, coords)
            Q += Jv.T @ (seg.disk_mass_g * g)
    return Q


def xs_to_psi(xs: list[float]) -> np.ndarray:
    """Flat bending vectors [x_1, y_1, ...] -> (S, 2) rows (theta, phi), rad."""
    a = np.asarray(xs, dtype=float).reshape(-1, 2)
    return np.column_stack((np.hypot(a[:, 0], a[:, 1]), np.arctan2(a[:, 1], a[:, 0])))


def tip_load_force(
    psi: np.ndarray, params: RobotParams, coords: str = "psi", weight: bool = True
) -> np.ndarray:
    """Generalised force of the tip load (2S,), J_tip^T F (N*mm per rad).

    F = m_tip g + F_tip: the payload's weight (``params.tip_mass_g``, g; left out with
    ``weight=False``) and the tip force (``params.tip_force_N``, N, base frame), both acting at
    the tip point of the last segment (arc fraction 1); J_tip its linear Jacobian
    (:func:`cdcr_ctl.model.cc_disk.kinematics.point_jacobian`). Virtual work of a point force: the
    force F at a point p does F . dp = F . J dpsi, so it enters eq. 9 as Q = J^T F, like the
    disk weights.
    """
    psi = np.asarray(psi, dtype=float).reshape(-1, 2)
    F = np.asarray(params.tip_force_N, dtype=float)
    if weight:
        F = F + params.tip_mass_g * G_MM_S2_TO_N * np.asarray(params.gravity_mm_s2, dtype=float)
    if not np.any(F):
        return np.zeros(2 * psi.shape[0])
    S = params.n_segments
    _, Jv, _ = point_jacobian(psi, params.lengths_mm, S - 1, 1.0, coords)
    return Jv.T @ F


def moment_demand(psi: np.ndarray, params: RobotParams, effects: Effects) -> np.ndarray:
    """m_i = (EI_i/l_i) x_i - Q_x,i for every segment, (S, 2) in N*mm (moment-vector form).

    Q_x: the disk weights (when ``effects.gravity``) and the tip load (always: a payload or tip
    force the config names acts whatever the disk-weight switch).
    """
    x = psi_to_x(psi)
    m = np.array([seg.EI_Nmm2 / seg.length_mm * x[i] for i, seg in enumerate(params.segments)])
    if effects.gravity:
        m = m - gravity_force(psi, params, "x").reshape(-1, 2)
    m = m - tip_load_force(psi, params, "x").reshape(-1, 2)
    return m


def bend_factors(psi: np.ndarray, params: RobotParams, s: np.ndarray, effects: Effects):
    """Fbar (K, S): mean span tension of cable k in segment i over its anchor tension (eq. 23).

    Hole by hole over the exact chord wrap angles; 1 without disk friction; 0 where the cable does
    not cross the segment.
    """
    K, S = params.n_cables, params.n_segments
    F = np.zeros((K, S))
    for k, c in enumerate(params.cables):
        mu = c.mu_disk if effects.disk_friction else 0.0
        wraps = wrap_angles(psi, params, k)
        spans, _ = propagate(1.0, wraps, mu, float(s[k]))
        # keep the spans (drop disk channels when disks are thick)
        j = 0
        for i in range(c.segment + 1):
            seg = params.segments[i]
            step = 2 if seg.disk_thickness_mm > 0.0 else 1
            vals = []
            for _ in range(seg.n_disks):
                vals.append(spans[j])
                j += step
            F[k, i] = float(np.mean(vals))
    return F


def pretension_tensions(A: np.ndarray, b: np.ndarray, T0: np.ndarray, tol: float = 1e-9):
    """Minimum-sum tensions T >= T0 with A T = b (A: 2 x m), the pretension rule (eq. 10).

    Writes T = T0 + y, y >= 0, A y = b - A T0 =: b'. An optimal vertex has at most two non-zero
    y: try every pair of cables and keep the feasible one of least sum. Raises
    :class:`ModelError` if no cable pair can produce b' with non-negative extra tension.
    """
    A = np.asarray(A, dtype=float)
    T0 = np.asarray(T0, dtype=float)
    bp = np.asarray(b, dtype=float) - A @ T0
    m = A.shape[1]
    scale = max(1.0, float(np.abs(A).max()))
    if float(np.abs(bp).max()) <= tol * scale:
        return T0.copy()
    best, best_sum = None, math.inf
    for j, k in itertools.combinations(range(m), 2):
        det = A[0, j] * A[1, k] - A[1, j] * A[0, k]
        if abs(det) < 1e-14 * scale * scale:
            continue
        yj = (bp[0] * A[1, k] - bp[1] * A[0, k]) / det
        yk = (A[0, j] * bp[1] - A[1, j] * bp[0]) / det
        if yj >= -tol and yk >= -tol and yj + yk < best_sum:
            best_sum = yj + yk
            best = (j, k, max(yj, 0.0), max(yk, 0.0))
    if best is None:
        raise ModelError(f"no pair of cables yields the moment {bp.tolist()} with tension >= T0")
    T = T0.copy()
    T[best[0]] += best[2]
    T[best[1]] += best[3]
    return T


def solve_tensions(
    psi: np.ndarray,
    params: RobotParams,
    effects: Effects,
    s: np.ndarray | None = None,
) -> np.ndarray:
    """Anchor tensions (K,), N, by back-substitution from the tip (coupling form, eq. 11-15).

    Segment S first (only its own cables load it), then each proximal segment with the coupling
    c_i of the distal cables moved to the right-hand side; the pretension rule per segment.
    """
    K, S = params.n_cables, params.n_segments
    s_arr = np.zeros(K) if s is None else np.asarray(s, dtype=float)
    F = bend_factors(psi, params, s_arr, effects)
    m = moment_demand(psi, params, effects)
    T = np.zeros(K)
    arms = np.array(
        [
            c.routing_radius_mm * np.array([math.cos(c.hole_angle_rad), math.sin(c.hole_angle_rad)])
            for c in params.cables
        ]
    )
    for i in range(S - 1, -1, -1):
        b = m[i].copy()
        if effects.coupling:
            for k, c in enumerate(params.cables):
                if c.segment > i:
                    b -= effects.coupling_gain * T[k] * F[k, i] * arms[k]
        own = list(params.cables_of(i))
        A = np.array([arms[k] for k in own]).T
        T0 = np.array([params.cables[k].pretension_N for k in own])
        T[own] = pretension_tensions(A, b, T0) / F[own, i]  # rule on the mean tension
    return T


def solve_tensions_all_cables(psi: np.ndarray, params: RobotParams, effects: Effects) -> np.ndarray:
    """Frictionless all-cables form (eq. 9 for every segment at once), by linear programming.

    minimise sum T subject to J_qpsi^T T = grad U - Q_psi and T >= T0, with the full
    multi-segment Jacobian of :func:`cdcr_ctl.model.cc_disk.routing.cable_jacobian` (phi rows
    divided by theta where theta > 0). Reference for :func:`solve_tensions` (scipy linprog, slow).
    """
    psi = np.asarray(psi, dtype=float).reshape(-1, 2)
    J = cable_jacobian(psi, params)
    rhs = elastic_gradient(psi, params)
    if effects.gravity:
        rhs = rhs - gravity_force(psi, params, "psi")
    rhs = rhs - tip_load_force(psi, params, "psi")
    Q_tip_x = tip_load_force(psi, params, "x")
    rows, vals = [], []
    for i in range(psi.shape[0]):
        rows.append(J[:, 2 * i])
        vals.append(rhs[2 * i])
        th = psi[i, 0]
        if th > 1e-9:
            rows.append(J[:, 2 * i + 1] / th)
            vals.append(rhs[2 * i + 1] / th)
        else:  # phi row divided by theta, taken to its limit
            Bx = np.zeros(params.n_cables)
            for k, c in enumerate(params.cables):
                if c.segment >= i:
                    Bx[k] = c.routing_radius_mm * math.sin(c.hole_angle_rad - psi[i, 1])
            rows.append(Bx)
            g_phi = 0.0
            u_perp = np.array([-math.sin(psi[i, 1]), math.cos(psi[i, 1])])
            if effects.gravity:
                g_phi = -gravity_force(psi, params, "x")[2 * i : 2 * i + 2] @ u_perp
            g_phi -= Q_tip_x[2 * i : 2 * i + 2] @ u_perp
            vals.append(g_phi)
    A_eq = np.array(rows)
    b_eq = np.array(vals)
    T0 = np.array([c.pretension_N for c in params.cables])
    res = linprog(
        np.ones(params.n_cables),
        A_eq=A_eq,
        b_eq=b_eq,
        bounds=list(zip(T0, [None] * len(T0), strict=True)),
        method="highs",
    )
    if not res.success:
        raise ModelError(f"all-cables statics infeasible: {res.message}")
    return res.x


def coupling_force(psi_i: np.ndarray, psi_next: np.ndarray, M_next_Nmm: float) -> np.ndarray:
    """Generalised force (theta_i, phi_i) of the distal cables on segment i (eq. 11-15 corrected).

    M_next acts in segment i+1's bending plane: the 2-vector M u_{i+1} projected on
    (d/dtheta_i, d/dphi_i) gives M [cos(phi_{i+1} - phi_i), theta_i sin(phi_{i+1} - phi_i)].
    """
    th_i, ph_i = float(psi_i[0]), float(psi_i[1])
    ph_n = float(psi_next[1])
    d = ph_n - ph_i
    return M_next_Nmm * np.array([math.cos(d), th_i * math.sin(d)])


def moment_residual(
    psi: np.ndarray, params: RobotParams, effects: Effects, T: np.ndarray, s: np.ndarray
) -> np.ndarray:
    """(S, 2) residual of the moment-vector equations for given anchor tensions (N*mm)."""
    F = bend_factors(psi, params, np.asarray(s, dtype=float), effects)
    m = moment_demand(psi, params, effects)
    out = -m
    for k, c in enumerate(params.cables):
        arm = c.routing_radius_mm * np.array(
            [math.cos(c.hole_angle_rad), math.sin(c.hole_angle_rad)]
        )
        for i in range(c.segment + 1):
            if i == c.segment:
                out[i] += T[k] * F[k, i] * arm
            elif effects.coupling:
                out[i] += effects.coupling_gain * T[k] * F[k, i] * arm
    return out
