"""Forward kinematics of the universal-joint arm (Yang et al. 2022, eq. 1-2): sub-joint
and segment transforms (eq. 1 with eq. 4's Trans-Rot-Rot-Trans), the tip frame (eq. 2), and the mass
points the gravity statics need.

Units: mm, rad; frames as in :mod:`cdcr_ctl.model.ujoint`.
"""

from __future__ import annotations

import numpy as np

from cdcr_ctl.model.ujoint.kinematics import (
    _as_theta,
    _homog,
    _rotation_rows,
    _trans_z,
    rot_x,
    rot_y,
)
from cdcr_ctl.model.ujoint.params import UJointArm, UJointSegment


# =========================================================================== eq. 1-2
def subjoint_transform(theta_a: float, theta_b: float, seg: UJointSegment) -> np.ndarray:
    """D1 of a sub-joint -> D1 of the next (4x4): Trans(z,d) Rx Ry Trans(z,d) Trans(z,link),
    i.e. rotation R = Rx Ry and translation d e_z + (d + link) R e_z."""
    R = _rotation_rows(theta_a, theta_b, 0).reshape(3, 3)
    d = seg.half_gap_mm
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = (d + seg.link_mm) * R[:, 2]
    T[2, 3] += d
    return T


def segment_transform(theta_a: float, theta_b: float, seg: UJointSegment) -> np.ndarray:
    """T_sn of eq. 2: segment base (first D1) -> segment tip (D1 after the last link), 4x4."""
    S = subjoint_transform(theta_a, theta_b, seg)
    T = S
    for _ in range(seg.n_subjoints - 1):
        T = T @ S
    return T


def tip_transform(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Robot base -> tip (end of the tip link), eq. 1: T_base T_s1 ... T_sN T_tip (4x4, mm)."""
    t = _as_theta(arm, theta)
    T = _trans_z(arm.base_link_mm)
    for n, seg in enumerate(arm.segments):
        T = T @ segment_transform(t[n, 0], t[n, 1], seg)
    return T @ _trans_z(arm.tip_link_mm)


def tip_position(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Tip position in the robot base frame (mm)."""
    return tip_transform(arm, theta)[:3, 3]


def mass_points(arm: UJointArm, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions (K, 3) mm, masses (K,) g) of every moving link and the tip mass, base frame.

    Link i of a segment (after sub-joint i) has its mass at the middle of its tube.
    """
    t = _as_theta(arm, theta)
    pts: list[np.ndarray] = []
    ms: list[float] = []
    T = _trans_z(arm.base_link_mm)
    for n, seg in enumerate(arm.segments):
        R = rot_x(t[n, 0]) @ rot_y(t[n, 1])
        d = seg.half_gap_mm
        for _ in range(seg.n_subjoints):
            T = T @ _trans_z(d) @ _homog(R, (0.0, 0.0, 0.0)) @ _trans_z(d)
            if seg.link_mass_g > 0:
                pts.append(T[:3, :3] @ np.array([0.0, 0.0, 0.5 * seg.link_mm]) + T[:3, 3])
                ms.append(seg.link_mass_g)
            T = T @ _trans_z(seg.link_mm)
    if arm.tip_mass_g > 0:
        pts.append(T[:3, :3] @ np.array([0.0, 0.0, 0.5 * arm.tip_link_mm]) + T[:3, 3])
        ms.append(arm.tip_mass_g)
    if not pts:
        return np.zeros((0, 3)), np.zeros(0)
    return np.array(pts), np.array(ms)
