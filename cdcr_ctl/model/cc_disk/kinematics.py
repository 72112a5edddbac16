"""Constant-curvature backbone kinematics (Qi et al. 2023 eq. 1-3 and 6).

One segment is a circular arc of fixed length ``l`` (mm) described by ``psi_i = (theta_i, phi_i)``:
bend angle theta (rad) and bending-plane direction phi (rad, about the segment base frame's z,
from its x). Equivalent smooth coordinates are the *bending vector* ``x_i = theta_i (cos phi_i,
sin phi_i)`` (rad): every function of x below is analytic through the straight pose, where phi is
undefined. Frames: segment i's base frame is segment i-1's tip frame; segment 1's base frame is the
robot base frame (z along the straight backbone, x towards the hole at angle 0).

Ratios such as sin(t)/t are evaluated by Taylor series for |t| < 0.1 so positions and Jacobians are
finite and smooth at theta = 0 (NOTES: eq. 2 and 6 are 0/0 there); above it 1 - cos t is written
as 2 sin^2(t/2) to avoid cancellation.
"""

from __future__ import annotations

import math

import numpy as np

#: Below this |theta| (rad) the trigonometric ratios use their Taylor series (error < 1e-16).
SERIES_BELOW = 0.1


# --------------------------------------------------------------------------- scalar ratios
def s1(t: float) -> float:
    """sin(t)/t (-> 1)."""
    if abs(t) < SERIES_BELOW:
        t2 = t * t
        return 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)))
    return math.sin(t) / t


def c2(t: float) -> float:
    """(1 - cos t)/t^2 (-> 1/2)."""
    if abs(t) < SERIES_BELOW:
        t2 = t * t
        return 0.5 - t2 / 24.0 + t2 * t2 / 720.0 - t2**3 / 40320.0 + t2**4 / 3628800.0
    h = math.sin(0.5 * t)
    return 2.0 * h * h / (t * t)


def c1(t: float) -> float:
    """(1 - cos t)/t (-> 0)."""
    return t * c2(t)


def d1(t: float) -> float:
    """(t cos t - sin t)/t^3 = s1'(t)/t (-> -1/3)."""
    if abs(t) < SERIES_BELOW:
        t2 = t * t
        return -1.0 / 3.0 + t2 / 30.0 - t2 * t2 / 840.0 + t2**3 / 45360.0
    return (t * math.cos(t) - math.sin(t)) / t**3


def d2(t: float) -> float:
    """(t sin t - 2 (1 - cos t))/t^4 = c2'(t)/t (-> -1/12)."""
    if abs(t) < SERIES_BELOW:
        t2 = t * t
        return -1.0 / 12.0 + t2 / 180.0 - t2 * t2 / 6720.0 + t2**3 / 453600.0
    h = math.sin(0.5 * t)
    return (t * math.sin(t) - 4.0 * h * h) / t**4


def e2(t: float) -> float:
    """(t - sin t)/t^3 = (1 - s1(t))/t^2 (-> 1/6)."""
    if abs(t) < SERIES_BELOW:
        t2 = t * t
        return 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2**3 / 362880.0
    return (t - math.sin(t)) / t**3


def g1(t: float) -> float:
    """(t sin t + cos t - 1)/t^2 = d/dt[(1 - cos t)/t] (eq. 6, -> 1/2)."""
    if abs(t) < SERIES_BELOW:
        t2 = t * t
        return 0.5 - t2 / 8.0 + t2 * t2 / 144.0 - t2**3 / 5760.0
    h = math.sin(0.5 * t)
    return (t * math.sin(t) - 2.0 * h * h) / (t * t)


# --------------------------------------------------------------------------- coordinates
def bend_vector(theta: float, phi: float) -> np.ndarray:
    """x = theta (cos phi, sin phi) (rad)."""
    return np.array([theta * math.cos(phi), theta * math.sin(phi)])


def bend_angles(x: np.ndarray) -> tuple[float, float]:
    """(theta >= 0, phi) of a bending vector; phi = 0 at the straight pose."""
    theta = math.hypot(float(x[0]), float(x[1]))
    phi = math.atan2(float(x[1]), float(x[0])) if theta > 0.0 else 0.0
    return theta, phi


def psi_to_x(psi: np.ndarray) -> np.ndarray:
    """(S, 2) rows (theta, phi) -> (S, 2) bending vectors."""
    psi = np.asarray(psi, dtype=float).reshape(-1, 2)
    return np.column_stack((psi[:, 0] * np.cos(psi[:, 1]), psi[:, 0] * np.sin(psi[:, 1])))


def x_to_psi(x: np.ndarray) -> np.ndarray:
    """(S, 2) bending vectors -> (S, 2) rows (theta >= 0, phi); phi = 0 where straight."""
    x = np.asarray(x, dtype=float).reshape(-1, 2)
    theta = np.hypot(x[:, 0], x[:, 1])
    phi = np.where(theta > 0.0, np.arctan2(x[:, 1], x[:, 0]), 0.0)
    return np.column_stack((theta, phi))


# --------------------------------------------------------------------------- one segment
def rotation(theta: float, phi: float) -> np.ndarray:
    """Relative rotation base -> tip of one segment, Qi et al. 2023 eq. 1 (3x3).

    R = Rot(z, phi) Rot(y, theta) Rot(z, -phi). The printed element (2,1) ``c phi s phi c theta``
    is a typo (NOTES): the xy block is symmetric, so (2,1) = (1,2) = c phi s phi (c theta - 1).
    """
    ct, st, cp, sp = math.cos(theta), math.sin(theta), math.cos(phi), math.sin(phi)
    return np.array(
        [
            [ct * cp * cp + sp * sp, cp * sp * (ct - 1.0), cp * st],
            [cp * sp * (ct - 1.0), sp * sp * ct + cp * cp, sp * st],
            [-cp * st, -sp * st, ct],
        ]
    )


def position(theta: float, phi: float, length_mm: float) -> np.ndarray:
    """Tip position of one segment in its base frame (mm), Qi et al. 2023 eq. 2.

    p = l/theta (c phi (1 - c theta), s phi (1 - c theta), s theta), written with the ratios
    (1 - cos t)/t and sin t/t so that theta = 0 gives the straight segment (0, 0, l).
    """
    a = length_mm * c1(theta)
    return np.array([a * math.cos(phi), a * math.sin(phi), length_mm * s1(theta)])


def segment_jacobian(theta: float, phi: float, length_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(J_v, J_w), each 3x2, of one segment w.r.t. (theta, phi); Qi et al. 2023 eq. 6.

    Tip linear velocity (mm/s) = J_v psi_dot and angular velocity (rad/s) = J_w psi_dot, both in
    the segment base frame. Finite at theta = 0 (where the phi column vanishes: rank loss).
    """
    cp, sp = math.cos(phi), math.sin(phi)
    g = g1(theta)
    h = theta * d1(theta)  # (theta cos theta - sin theta)/theta^2
    a = c1(theta)  # (1 - cos theta)/theta
    L = length_mm
    Jv = np.array([[L * cp * g, -L * a * sp], [L * sp * g, L * a * cp], [L * h, 0.0]])
    st, ct = math.sin(theta), math.cos(theta)
    Jw = np.array([[-sp, -cp * st], [cp, -sp * st], [0.0, 1.0 - ct]])
    return Jv, Jw


def segment_pose_x(x: np.ndarray, length_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(R, p) of one segment from its bending vector x (rad): eq. 1-2 in smooth coordinates.

    R is the rotation by theta about the in-plane axis (-sin phi, cos phi, 0) (Rodrigues form of
    eq. 1); p = l ((1 - cos t)/t^2 x, sin t / t).
    """
    x0, x1 = float(x[0]), float(x[1])
    t = math.hypot(x0, x1)
    a, b = s1(t), c2(t)
    # K = skew(axis * theta) with axis * theta = (-x1, x0, 0)
    K = np.array([[0.0, 0.0, x0], [0.0, 0.0, x1], [-x0, -x1, 0.0]])
    R = np.eye(3) + a * K + b * (K @ K)
    p = np.array([length_mm * b * x0, length_mm * b * x1, length_mm * a])
    return R, p


def segment_jacobian_x(x: np.ndarray, length_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(J_v, J_w), each 3x2, of one segment w.r.t. its bending vector x; smooth through x = 0.

    Derived from eq. 2 written as p = l (c2(t) x, s1(t)): dp_xy/dx = l (c2 I + d2 x x^T),
    dp_z/dx = l d1 x^T. From eq. 6 with theta_dot = u.x_dot and phi_dot = v.x_dot / theta
    (u = x/theta, v = u rotated by +90 deg): omega_xy = (J90 + e2 x x_perp^T) x_dot and
    omega_z = c2 x_perp^T x_dot, with x_perp = (-x1, x0) and J90 the +90 deg rotation.
    """
    x0, x1 = float(x[0]), float(x[1])
    t = math.hypot(x0, x1)
    L = length_mm
    cc, dd, d_1, ee = c2(t), d2(t), d1(t), e2(t)
    Jv = np.array(
        [
            [L * (cc + dd * x0 * x0), L * dd * x0 * x1],
            [L * dd * x0 * x1, L * (cc + dd * x1 * x1)],
            [L * d_1 * x0, L * d_1 * x1],
        ]
    )
    xp0, xp1 = -x1, x0
    Jw = np.array(
        [
            [ee * x0 * xp0, -1.0 + ee * x0 * xp1],
            [1.0 + ee * x1 * xp0, ee * x1 * xp1],
            [cc * xp0, cc * xp1],
        ]
    )
    return Jv, Jw


# --------------------------------------------------------------------------- the chain
def _as_psi(psi: np.ndarray) -> np.ndarray:
    return np.asarray(psi, dtype=float).reshape(-1, 2)


def chain(psi: np.ndarray, lengths_mm: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Tip frames (R_i, P_i) of every segment in the robot base frame, Qi et al. 2023 eq. 3.

    R_i = R_{i-1} R(psi_i), P_i = R_{i-1} p(psi_i) + P_{i-1}, with R_0 = I, P_0 = 0.
    """
    psi = _as_psi(psi)
    R, P = np.eye(3), np.zeros(3)
    out = []
    for (theta, phi), length in zip(psi, lengths_mm, strict=True):
        P = R @ position(theta, phi, float(length)) + P
        R = R @ rotation(theta, phi)
        out.append((R, P))
    return out


def tip_position(psi: np.ndarray, lengths_mm: np.ndarray) -> np.ndarray:
    """Tip position of the last segment in the robot base frame (mm), eq. 3: the
    :func:`tip_frame_fast` of the bending vectors of ``psi`` (S, 2)."""
    xs = psi_to_x(psi).ravel().tolist()
    return np.array(tip_frame_fast(xs, [float(v) for v in lengths_mm])[1])


def point_jacobian(
    psi: np.ndarray, lengths_mm: np.ndarray, segment: int, fraction: float, coords: str = "psi"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position (3,), linear (3, 2S) and angular (3, 2S) Jacobians of a backbone point.

    The point lies on segment ``segment`` (0-based) at arc fraction ``fraction`` in [0, 1] of its
    length; everything in the robot base frame. ``coords`` = ``"psi"`` differentiates w.r.t.
    (theta_i, phi_i) (eq. 6 chained), ``"x"`` w.r.t. the bending vectors (smooth at theta = 0).
    Segment j < segment moves the point by R_{j-1} J_v,j dpsi_j + (R_{j-1} J_w,j dpsi_j) x
    (point - P_j); the point's own segment by R_{i-1} d p(sigma psi; sigma l)/d psi_i, where the
    partial arc has bend sigma*theta and length sigma*l.
    """
    psi = _as_psi(psi)
    S = psi.shape[0]
    frames = chain(psi, lengths_mm)
    R_prev = np.eye(3) if segment == 0 else frames[segment - 1][0]
    P_prev = np.zeros(3) if segment == 0 else frames[segment - 1][1]
    theta, phi = psi[segment]
    sig = float(fraction)
    l_i = float(lengths_mm[segment])
    if coords == "psi":
        p_loc = position(sig * theta, phi, sig * l_i)
        Jv_loc, Jw_loc = segment_jacobian(sig * theta, phi, sig * l_i)
        Jv_loc = Jv_loc * np.array([sig, 1.0])
        Jw_loc = Jw_loc * np.array([sig, 1.0])
    elif coords == "x":
        xv = bend_vector(theta, phi)
        _, p_loc = segment_pose_x(sig * xv, sig * l_i)
        Jv_loc, Jw_loc = segment_jacobian_x(sig * xv, sig * l_i)
        Jv_loc = sig * Jv_loc
        Jw_loc = sig * Jw_loc
    else:
        raise ValueError(f"coords must be 'psi' or 'x', not {coords!r}")
    point = P_prev + R_prev @ p_loc
    Jv = np.zeros((3, 2 * S))
    Jw = np.zeros((3, 2 * S))
    Jv[:, 2 * segment : 2 * segment + 2] = R_prev @ Jv_loc
    Jw[:, 2 * segment : 2 * segment + 2] = R_prev @ Jw_loc
    R_j = np.eye(3)
    for j in range(segment):
        th, ph = psi[j]
        l_j = float(lengths_mm[j])
        if coords == "psi":
            Jv_j, Jw_j = segment_jacobian(th, ph, l_j)
        else:
            Jv_j, Jw_j = segment_jacobian_x(bend_vector(th, ph), l_j)
        w = R_j @ Jw_j
        arm = point - frames[j][1]
        Jv[:, 2 * j : 2 * j + 2] = R_j @ Jv_j + np.cross(w.T, arm).T
        Jw[:, 2 * j : 2 * j + 2] = w
        R_j = frames[j][0]
    return point, Jv, Jw


def robot_jacobian(psi: np.ndarray, lengths_mm: np.ndarray, coords: str = "psi") -> np.ndarray:
    """Whole-robot tip Jacobian (6, 2S): rows = linear (mm/rad) then angular, base frame."""
    psi = _as_psi(psi)
    _, Jv, Jw = point_jacobian(psi, lengths_mm, psi.shape[0] - 1, 1.0, coords)
    return np.vstack((Jv, Jw))


def disk_positions(psi: np.ndarray, lengths_mm: np.ndarray, n_disks: list[int]) -> np.ndarray:
    """Centres of all moving disks (base frame, mm), segment by segment, base to tip.

    Segment i has ``n_disks[i]`` disks at arc s = m l_i / n_i, m = 1..n_i (the last one is its tip).
    """
    psi = _as_psi(psi)
    frames = chain(psi, lengths_mm)
    out = []
    R, P = np.eye(3), np.zeros(3)
    for i, (theta, phi) in enumerate(psi):
        n = int(n_disks[i])
        for m in range(1, n + 1):
            sig = m / n
            out.append(P + R @ position(sig * theta, phi, sig * float(lengths_mm[i])))
        R, P = frames[i]
    return np.array(out)


def tip_position_fast(xs: list[float], lengths_mm: list[float]) -> tuple[float, float, float]:
    """Tip position (mm, base frame) from flat bending vectors, eq. 1-3 on plain floats."""
    return tip_frame_fast(xs, lengths_mm)[1]


def tip_frame_fast(
    xs: list[float], lengths_mm: list[float]
) -> tuple[tuple[tuple[float, float, float], ...], tuple[float, float, float]]:
    """Tip frame of the last segment in the robot base frame from flat bending vectors
    ``xs`` (x_1, y_1, x_2, ...; rad), eq. 1-3 on plain floats: (R rows, p in mm).

    The same frame as ``chain(psi, lengths_mm)[-1]`` within rounding: :func:`chain` gives every
    segment's frame (the Jacobians and backbone points use them), this the tip's alone, once per
    control cycle and per simulated step (``benchmarks/bench_hot_paths.py`` measures the two;
    ``tests/model/test_cc_kinematics.py`` holds them equal). Each segment in
    bending-vector form (X, Y) = theta (cos phi, sin phi), t = theta, a = s1(t), b = c2(t):
    R = [[1 - b X^2, -b X Y, a X], [-b X Y, 1 - b Y^2, a Y], [-a X, -a Y, 1 - b t^2]] (eq. 1)
    and p = l (b X, b Y, a) (eq. 2), chained R_i = R_{i-1} R, P_i = R_{i-1} p + P_{i-1} (eq. 3).
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    px = py = pz = 0.0
    for i, L in enumerate(lengths_mm):
        X, Y = xs[2 * i], xs[2 * i + 1]
        t = math.sqrt(X * X + Y * Y)
        a, b = s1(t), c2(t)
        lx, ly, lz = L * b * X, L * b * Y, L * a
        px += r00 * lx + r01 * ly + r02 * lz
        py += r10 * lx + r11 * ly + r12 * lz
        pz += r20 * lx + r21 * ly + r22 * lz
        q00, q01, q02 = 1.0 - b * X * X, -b * X * Y, a * X
        q10, q11, q12 = -b * X * Y, 1.0 - b * Y * Y, a * Y
        q20, q21, q22 = -a * X, -a * Y, 1.0 - b * t * t
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = (
            r00 * q00 + r01 * q10 + r02 * q20,
            r00 * q01 + r01 * q11 + r02 * q21,
            r00 * q02 + r01 * q12 + r02 * q22,
            r10 * q00 + r11 * q10 + r12 * q20,
            r10 * q01 + r11 * q11 + r12 * q21,
            r10 * q02 + r11 * q12 + r12 * q22,
            r20 * q00 + r21 * q10 + r22 * q20,
            r20 * q01 + r21 * q11 + r22 * q21,
            r20 * q02 + r21 * q12 + r22 * q22,
        )
    return ((r00, r01, r02), (r10, r11, r12), (r20, r21, r22)), (px, py, pz)
