"""Forward kinematics of the vertebra arm (fuel-tank vertebra robot paper, eq. 1-2).

The series that keep the arc formulas analytic through the straight pose (:func:`s1`,
:func:`d1`, :func:`d2`, :func:`c2`; NOTES eq. 2, 6), the bending vector x = theta (cos phi,
sin phi), the twist-free joint rotation of eq. 1 (:func:`joint_rotation`, :func:`arc_transform`,
:func:`joint_transform`), the tip frame of eq. 2 (:func:`tip_transform`) and the mass points.

Units: mm, rad.
"""

from __future__ import annotations

import math

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.vertebra.params import D2_SERIES_BELOW, SERIES_BELOW, VertebraArm, VertebraJoint


# =========================================================================== series
def s1(u: float) -> float:
    """sin(u)/u (-> 1)."""
    if abs(u) < SERIES_BELOW:
        u2 = u * u
        return 1.0 - u2 / 6.0 * (1.0 - u2 / 20.0 * (1.0 - u2 / 42.0 * (1.0 - u2 / 72.0)))
    return math.sin(u) / u


def d1(u: float) -> float:
    """(u cos u - sin u)/u^3 = s1'(u)/u (-> -1/3)."""
    if abs(u) < SERIES_BELOW:
        u2 = u * u
        return -1.0 / 3.0 + u2 / 30.0 - u2 * u2 / 840.0 + u2**3 / 45360.0
    return (u * math.cos(u) - math.sin(u)) / u**3


def d2(u: float) -> float:
    """d1'(u)/u = (3 sin u - 3 u cos u - u^2 sin u)/u^5 (-> 1/15). Its closed form cancels to
    O(u^5), so the series (next term 1.9e-8 u^8) is used up to :data:`D2_SERIES_BELOW`."""
    if abs(u) < D2_SERIES_BELOW:
        u2 = u * u
        return 1.0 / 15.0 - u2 / 210.0 + u2 * u2 / 7560.0 - u2**3 / 498960.0
    return (3.0 * math.sin(u) - 3.0 * u * math.cos(u) - u * u * math.sin(u)) / u**5


def c2(u: float) -> float:
    """(1 - cos u)/u^2 (-> 1/2)."""
    if abs(u) < SERIES_BELOW:
        u2 = u * u
        return 0.5 - u2 / 24.0 + u2 * u2 / 720.0 - u2**3 / 40320.0
    h = math.sin(0.5 * u)
    return 2.0 * h * h / (u * u)


def bend_vector(theta: float, phi: float) -> np.ndarray:
    """x = theta (cos phi, sin phi) (rad)."""
    return np.array([theta * math.cos(phi), theta * math.sin(phi)])


def psi_from_x(x: np.ndarray, phi_if_straight: float = 0.0) -> tuple[float, float]:
    """(theta >= 0, phi) of a bending vector; ``phi_if_straight`` where theta = 0."""
    theta = math.hypot(float(x[0]), float(x[1]))
    phi = math.atan2(float(x[1]), float(x[0])) if theta > 0.0 else phi_if_straight
    return theta, phi


def _psi_array(psi: np.ndarray, n: int) -> np.ndarray:
    p = np.asarray(psi, dtype=float)
    if p.shape != (n, 2):
        raise ModelError(f"joint poses must have shape ({n}, 2), got {p.shape}")
    return p


# =========================================================================== eq. 1-2
def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(b: float) -> np.ndarray:
    c, s = math.cos(b), math.sin(b)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(g: float) -> np.ndarray:
    c, s = math.cos(g), math.sin(g)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def joint_rotation(theta: float, phi: float) -> np.ndarray:
    """Rotation of a joint (or of one gap with theta/n), eq. 1: Rz(phi) Ry(theta) Rz(-phi).

    Element (2,1) is c phi s phi (c theta - 1) (the symmetric xy block; NOTES on Qi eq. 1 apply
    to the same matrix printed here).
    """
    ct, st, cp, sp = math.cos(theta), math.sin(theta), math.cos(phi), math.sin(phi)
    return np.array(
        [
            [ct * cp * cp + sp * sp, cp * sp * (ct - 1.0), st * cp],
            [cp * sp * (ct - 1.0), cp * cp + sp * sp * ct, st * sp],
            [-st * cp, -st * sp, ct],
        ]
    )


def arc_transform(theta: float, phi: float, length_mm: float) -> np.ndarray:
    """Eq. 1 in full: the constant-curvature arc of length L, 4x4 (position finite at theta = 0:
    L/theta (1 - cos theta) = L theta c2(theta), L/theta sin theta = L s1(theta))."""
    T = np.eye(4)
    T[:3, :3] = joint_rotation(theta, phi)
    a = length_mm * theta * c2(theta)
    T[:3, 3] = (a * math.cos(phi), a * math.sin(phi), length_mm * s1(theta))
    return T


def _unit_transform(theta: float, phi: float, joint: VertebraJoint) -> np.ndarray:
    """One vertebra unit: half gap, the gap's rotation about the ball centre, half gap, disk."""
    T = np.eye(4)
    R = joint_rotation(theta / joint.n_gaps, phi)
    a = 0.5 * joint.gap_mm
    # Trans(z, a) R Trans(z, a + H)
    T[:3, :3] = R
    T[:3, 3] = np.array([0.0, 0.0, a]) + R @ np.array([0.0, 0.0, a + joint.hole_length_mm])
    return T


def joint_transform(theta: float, phi: float, joint: VertebraJoint) -> np.ndarray:
    """Joint base -> joint end (top face of its last disk), the exact vertebra chain (4x4, mm).

    Its rotation is eq. 1's; its position is the polygon of n units, which tends to eq. 1's arc
    as n grows (:func:`arc_transform`). In closed form (the product of the n units of
    :func:`_unit_transform`): with a = theta/n, k = (-sin phi, cos phi, 0) and a unit's
    translation t = (l0/2) e_z + (l0/2 + H) Rot(k, a) e_z (in the bending plane, k . t = 0), the
    end is sum_{l<n} Rot(k, l a) t = C t + S (k x t), C = sum_{l<n} cos(l a),
    S = sum_{l<n} sin(l a) (see :func:`_potential_batch`).
    """
    n = joint.n_gaps
    a = theta / n
    cp, sp = math.cos(phi), math.sin(phi)
    half = 0.5 * joint.gap_mm
    arm_mm = half + joint.hole_length_mm
    sa = math.sin(a)
    t0, t1, t2 = arm_mm * sa * cp, arm_mm * sa * sp, arm_mm * math.cos(a) + half
    C = S = 0.0
    for m in range(n):
        C += math.cos(m * a)
        S += math.sin(m * a)
    T = np.eye(4)
    T[:3, :3] = joint_rotation(theta, phi)
    # k x t = (cp t2, sp t2, -cp t0 - sp t1)
    T[:3, 3] = (C * t0 + S * cp * t2, C * t1 + S * sp * t2, C * t2 - S * (cp * t0 + sp * t1))
    return T


def tip_transform(arm: VertebraArm, psi: np.ndarray) -> np.ndarray:
    """Robot base -> tip, eq. 2: the product of the joints' transforms (4x4, mm)."""
    p = _psi_array(psi, arm.n_joints)
    T = np.eye(4)
    for i, j in enumerate(arm.joints):
        T = T @ joint_transform(p[i, 0], p[i, 1], j)
    return T


def tip_position(arm: VertebraArm, psi: np.ndarray) -> np.ndarray:
    """Tip position in the robot base frame (mm)."""
    return tip_transform(arm, psi)[:3, 3]


def mass_points(arm: VertebraArm, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions (K, 3) mm, masses (K,) g): every disk at its centre, and the tip mass."""
    p = _psi_array(psi, arm.n_joints)
    pts: list[np.ndarray] = []
    ms: list[float] = []
    T = np.eye(4)
    for i, j in enumerate(arm.joints):
        U = _unit_transform(p[i, 0], p[i, 1], j)
        centre = np.array([0.0, 0.0, -0.5 * j.hole_length_mm, 1.0])
        for _ in range(j.n_gaps):
            T = T @ U
            if j.disk_mass_g > 0:
                pts.append((T @ centre)[:3])
                ms.append(j.disk_mass_g)
    if arm.tip_mass_g > 0:
        pts.append(T[:3, 3].copy())
        ms.append(arm.tip_mass_g)
    if not pts:
        return np.zeros((0, 3)), np.zeros(0)
    return np.array(pts), np.array(ms)
