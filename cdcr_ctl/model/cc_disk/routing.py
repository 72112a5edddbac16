"""Cable routing through the disk holes: displacements, Jacobians, exact chord paths, wrap angles.

Sign convention everywhere: ``q_k`` is the cable displacement PULLED IN by actuator k (mm);
positive shortens the cable inside the robot; q = 0 at the straight pose.

* Continuous routing, Qi et al. 2023 eq. 4 generalised to S segments (Yang et al. 2022 eq. 11): a
  cable anchored at the tip of segment a(k) runs through every proximal segment, so
  ``q_k = sum_{i <= a(k)} r_k theta_i cos(phi_i - gamma_k)``; eq. 5 is its Jacobian.
* Exact discrete-disk routing (eq. 20-22 geometry): straight spans between the holes of
  consecutive disks (and straight channels of the disk thickness through each disk).
* Wrap angles at each hole (eq. 21-22): the angle between consecutive span directions
  b = h/||h|| (NOTES: ``h = h/||h||`` means the unit span direction).

Closed forms used by the fast path (:mod:`cdcr_ctl.model.cc_disk.transfer`), derived here and
checked in the tests against the general polyline functions: in a constant-curvature segment with no
twist, a hole at (r cos gamma, r sin gamma) in every disk frame traces a circle of radius
R' = l/theta - r cos(phi - gamma) in a plane parallel to the bending plane, concentric with the
backbone arc. The chord between disks m and m+1 is therefore parallel to the backbone tangent at
the mid-angle, so the wrap angle at an inner hole is theta/n whatever the cable, and the chord is
2 R' sin(theta / 2n). With channels of thickness t the span joins points at radius
R'' = sqrt(R'^2 + t^2/4), angularly inset by da = atan(t / 2R'), and each channel edge wraps
theta/(2n).
"""

from __future__ import annotations

import math

import numpy as np

from cdcr_ctl.model.cc_disk.kinematics import position, rotation, s1
from cdcr_ctl.model.cc_disk.params import RobotParams


def _psi(psi: np.ndarray) -> np.ndarray:
    return np.asarray(psi, dtype=float).reshape(-1, 2)


# --------------------------------------------------------------------------- eq. 4-5
def cable_displacement(psi: np.ndarray, params: RobotParams) -> np.ndarray:
    """q (K,), mm pulled in, Qi et al. 2023 eq. 4 summed over the segments each cable crosses."""
    psi = _psi(psi)
    q = np.zeros(params.n_cables)
    for k, c in enumerate(params.cables):
        for i in range(c.segment + 1):
            theta, phi = psi[i]
            q[k] += c.routing_radius_mm * theta * math.cos(phi - c.hole_angle_rad)
    return q


def cable_jacobian(psi: np.ndarray, params: RobotParams) -> np.ndarray:
    """J_qpsi (K, 2S) = dq/dpsi, Qi et al. 2023 eq. 5 (sign: q pulled in, the paper uses length).

    dq_k/dtheta_i = r_k cos(phi_i - gamma_k), dq_k/dphi_i = -r_k theta_i sin(phi_i - gamma_k)
    for i <= a(k), zero for the segments distal to the cable's anchor. The phi columns vanish
    at theta_i = 0 (rank loss, NOTES eq. 10): use :func:`cable_matrix_x` there.
    """
    psi = _psi(psi)
    J = np.zeros((params.n_cables, 2 * psi.shape[0]))
    for k, c in enumerate(params.cables):
        r, g = c.routing_radius_mm, c.hole_angle_rad
        for i in range(c.segment + 1):
            theta, phi = psi[i]
            J[k, 2 * i] = r * math.cos(phi - g)
            J[k, 2 * i + 1] = -r * theta * math.sin(phi - g)
    return J


def cable_matrix_x(params: RobotParams) -> np.ndarray:
    """B (K, 2S) with q = B x (x the stacked bending vectors): eq. 4 is linear in x.

    r theta cos(phi - gamma) = r e_gamma . x with e_gamma = (cos gamma, sin gamma), so the rows
    are r_k e_gamma_k in the columns of every segment i <= a(k). Constant and full-rank-safe.
    """
    S = params.n_segments
    B = np.zeros((params.n_cables, 2 * S))
    for k, c in enumerate(params.cables):
        e = c.routing_radius_mm * np.array([math.cos(c.hole_angle_rad), math.sin(c.hole_angle_rad)])
        for i in range(c.segment + 1):
            B[k, 2 * i : 2 * i + 2] = e
    return B


# --------------------------------------------------------------------------- exact disk geometry
def disk_frames(psi: np.ndarray, params: RobotParams, upto: int) -> list[tuple[np.ndarray, ...]]:
    """Frames (R, P) of the disks of segments 0..upto, base disk first, base frame.

    The disk shared by two segments appears once. Disk m of segment i sits at arc m l_i / n_i.
    """
    psi = _psi(psi)
    R0, P0 = np.eye(3), np.zeros(3)
    out = [(R0, P0)]
    for i in range(upto + 1):
        seg = params.segments[i]
        theta, phi = psi[i]
        n = seg.n_disks
        for m in range(1, n + 1):
            sig = m / n
            R = R0 @ rotation(sig * theta, phi)
            P = P0 + R0 @ position(sig * theta, phi, sig * seg.length_mm)
            out.append((R, P))
        R0, P0 = out[-1]
    return out


def cable_path(psi: np.ndarray, params: RobotParams, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Polyline of cable k inside the robot (base frame, mm) and which pieces are disk channels.

    From the hole in the base disk's mid-plane to the hole in the mid-plane of the anchor disk.
    A disk of thickness t > 0 holds a straight channel along its normal n from h - t/2 n to
    h + t/2 n (only the upper half at the base disk, only the lower half at the anchor disk);
    with t = 0 the hole is a point. Returns (points (M, 3), is_channel (M-1,)).
    """
    c = params.cables[k]
    frames = disk_frames(psi, params, c.segment)
    thick = [params.segments[0].disk_thickness_mm]
    for i in range(c.segment + 1):
        seg = params.segments[i]
        thick += [seg.disk_thickness_mm] * seg.n_disks
    hole = c.routing_radius_mm * np.array(
        [math.cos(c.hole_angle_rad), math.sin(c.hole_angle_rad), 0.0]
    )
    last = len(frames) - 1
    pts: list[np.ndarray] = []
    chan: list[bool] = []
    for j, (R, P) in enumerate(frames):
        h = P + R @ hole
        half = 0.5 * thick[j] * R[:, 2]
        if j == 0:
            pts.append(h)
            if thick[j] > 0.0:
                pts.append(h + half)
                chan.append(True)
        elif thick[j] > 0.0:
            pts.append(h - half)
            chan.append(False)
            pts.append(h if j == last else h + half)
            chan.append(True)
        else:
            pts.append(h)
            chan.append(False)
    return np.array(pts), np.array(chan, dtype=bool)


def path_length(points: np.ndarray) -> float:
    """Length of a polyline (mm)."""
    return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


def chord_displacement(psi: np.ndarray, params: RobotParams, k: int) -> float:
    """Exact q_k (mm pulled in) through the disk holes: straight length minus the chord path.

    Converges to eq. 4 as the disk count grows (tested); differs from it at O(theta^2/n^2).
    """
    c = params.cables[k]
    L0 = sum(params.segments[i].length_mm for i in range(c.segment + 1))
    pts, _ = cable_path(psi, params, k)
    return L0 - path_length(pts)


def wrap_angles(psi: np.ndarray, params: RobotParams, k: int) -> np.ndarray:
    """Wrap angle eta (rad) at every contact of cable k, base first, eq. 21-22.

    eta = arccos(b_j . b_{j+1}) between consecutive unit piece directions; the cable enters the
    base disk along the base z axis. Contacts at the anchor disk are excluded (the cable is fixed
    there). With t = 0 there is one contact per hole (base disk and every inner disk); with t > 0
    one per channel edge. For one segment the sum is theta (1 - 1/(2n)) (t = 0), or close to it.
    """
    c = params.cables[k]
    pts, chan = cable_path(psi, params, k)
    d = np.diff(pts, axis=0)
    lengths = np.linalg.norm(d, axis=1)
    b = d / lengths[:, None]
    dirs = [np.array([0.0, 0.0, 1.0]), *list(b)]
    etas = []
    for j in range(len(dirs) - 1):  # atan2(|a x b|, a.b): accurate for small angles too
        cr = float(np.linalg.norm(np.cross(dirs[j], dirs[j + 1])))
        etas.append(math.atan2(cr, float(np.dot(dirs[j], dirs[j + 1]))))
    thick_base = params.segments[0].disk_thickness_mm > 0.0
    thick_tip = params.segments[c.segment].disk_thickness_mm > 0.0
    if thick_base:
        etas = etas[1:]  # z into the base channel: no contact angle
    if thick_tip and chan[-1]:
        etas = etas[:-1]  # last span into the anchor channel: the cable is fixed there
    return np.array(etas)


# --------------------------------------------------------------------------- closed forms
def segment_chord_shortening(
    theta: float, phi: float, length_mm: float, n_disks: int, r_mm: float, gamma: float, t_mm: float
) -> float:
    """Shortening (mm) of a cable's path inside one segment: l - (n t + n * span), exact chords.

    With a = theta/2n and R' = l/theta - r cos(phi - gamma): t = 0 gives span = 2 R' sin a; with
    channels, span = 2 R'' sin(a - da), R'' = sqrt(R'^2 + t^2/4), da = atan(t / 2R'), which
    expands (cos da = R'/R'', sin da = t/2R'') to 2 R' sin a - t cos a. Hence, exact at theta -> 0,

        l - L = l (1 - sin(a)/a) + 2 n r cos(phi - gamma) sin a - n t (1 - cos a).
    """
    n = n_disks
    a = 0.5 * theta / n
    rc = r_mm * math.cos(phi - gamma)
    h = math.sin(0.5 * a)
    return length_mm * (1.0 - s1(a)) + 2.0 * n * rc * math.sin(a) - 2.0 * n * t_mm * h * h


def boundary_wrap(
    theta_a: float, phi_a: float, n_a: int, theta_b: float, phi_b: float, n_b: int, thick: bool
) -> float:
    """Wrap angle (rad) at the disk joining segment a (proximal) and b (distal).

    The last span of a is parallel to a's tangent at theta_a (1 - 1/2n_a), the first span of b to
    b's tangent at theta_b / 2n_b. In the shared disk frame, with A = theta_a/2n_a and
    B = theta_b/2n_b: cos eta = cos A cos B - sin A sin B cos(phi_b - phi_a) (t = 0, evaluated
    as atan2(|t_a x t_b|, t_a . t_b) for accuracy at small angles). With a
    channel (t > 0) the cable touches both edges and eta = A + B.
    """
    A = 0.5 * theta_a / n_a
    B = 0.5 * theta_b / n_b
    if thick:
        return abs(A) + abs(B)
    return tangent_angle(A, math.cos(phi_a), math.sin(phi_a), B, math.cos(phi_b), math.sin(phi_b))


def tangent_angle(A: float, ca: float, sa: float, B: float, cb: float, sb: float) -> float:
    """Angle between t_a = (-sin A u_a, cos A) and t_b = (sin B u_b, cos B), u = (c, s).

    atan2(|t_a x t_b|, t_a . t_b) (equal to the arccos form, accurate near 0).
    """
    sA, cA, sB, cB = math.sin(A), math.cos(A), math.sin(B), math.cos(B)
    ax, ay, az = -sA * ca, -sA * sa, cA
    bx, by, bz = sB * cb, sB * sb, cB
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ax * bx + ay * by + az * bz)


def wrap_angles_closed_form(psi: np.ndarray, params: RobotParams, k: int) -> np.ndarray:
    """Wrap angles of cable k from the closed forms (same layout as :func:`wrap_angles`)."""
    psi = _psi(psi)
    c = params.cables[k]
    out: list[float] = []
    for i in range(c.segment + 1):
        seg = params.segments[i]
        theta, phi = psi[i]
        n = seg.n_disks
        thick = seg.disk_thickness_mm > 0.0
        if i == 0:
            out.append(abs(theta) / (2 * n))
        else:
            prev = params.segments[i - 1]
            if prev.disk_thickness_mm > 0.0:
                out += [abs(psi[i - 1][0]) / (2 * prev.n_disks), abs(theta) / (2 * n)]
            else:
                out.append(
                    boundary_wrap(psi[i - 1][0], psi[i - 1][1], prev.n_disks, theta, phi, n, False)
                )
        inner = abs(theta) / n
        for _ in range(n - 1):
            out += [inner / 2, inner / 2] if thick else [inner]
    return np.array(out)
