"""Deformation of the universal-joint arm's segments (Yang et al. 2022, eq. 14, 16-17).

Each segment is bent further by the drive torque of the distal ones: proportional (eq. 16-17)
or torque over stiffness (eq. 14) (:func:`deformation_rad`), its inverse (:func:`undeform`), and
the motion directions and cable friction state that switch it (eq. 17).

Units: rad, N*mm.
"""

from __future__ import annotations

import numpy as np

from cdcr_ctl.model.ujoint.kinematics import _hole_terms
from cdcr_ctl.model.ujoint.params import UJointArm


# =========================================================================== eq. 14-17
def deformation_rad(
    arm: UJointArm, theta_n: np.ndarray, distal_direction: np.ndarray
) -> np.ndarray:
    """Deformation Delta theta_de (N, 2) of each segment by the drive torque of the distal ones,
    eq. 14 / 16-17 as set out in :class:`DeformationParams` (rad).

    ``theta_n`` (N, 2): the segments' (undeformed) angles; ``distal_direction`` (N, 2):
    sgn(theta_dot) of every segment coordinate (+1, -1, 0), or a friction state in [-1, 1]
    (:func:`segment_friction_direction`). The most distal segment never deforms
    (no cable drives through it).
    """
    p = arm.deformation
    t = np.asarray(theta_n, dtype=float)
    s = np.clip(np.asarray(distal_direction, dtype=float), -1.0, 1.0)  # sgn, or a friction state
    out = np.zeros_like(t)
    if p.kind == "off":
        return out
    for n in range(arm.n_segments - 1):
        for m in range(n + 1, arm.n_segments):
            if p.kind == "proportional":
                out[n] += s[m] * p.eta * np.abs(t[n])
            else:
                out[n] += (
                    s[m]
                    * np.abs(np.sign(t[n]))
                    * (p.friction_torque_Nmm[m] / p.stiffness_Nmm_per_rad[n])
                )
    return out


def undeform(arm: UJointArm, theta_target: np.ndarray, distal_direction: np.ndarray) -> np.ndarray:
    """Angles theta_kin with theta_kin + deformation(theta_kin) = ``theta_target`` (N, 2).

    Proportional: theta = theta_kin (1 + eta sgn(theta_kin) sum_m sgn(theta_dot_m)); theta_kin
    has the sign of theta (eta (N - 1) < 1), so theta_kin = theta / (1 + eta sgn(theta) sum_m
    sgn(theta_dot_m)). Torque: theta_kin = theta - sum_m sgn(theta_dot_m) tau_m / k_n where
    theta != 0 (exact when |theta| exceeds the deformation, below which eq. 14 itself jumps).
    """
    p = arm.deformation
    t = np.asarray(theta_target, dtype=float)
    if p.kind == "off":
        return t.copy()
    s = np.sign(np.asarray(distal_direction, dtype=float))
    out = t.copy()
    for n in range(arm.n_segments - 1):
        drive = sum(s[m] for m in range(n + 1, arm.n_segments))
        if p.kind == "proportional":
            out[n] = t[n] / (1.0 + p.eta * np.sign(t[n]) * drive)
        else:
            out[n] = t[n] - np.abs(np.sign(t[n])) * sum(
                s[m] * p.friction_torque_Nmm[m] / p.stiffness_Nmm_per_rad[n]
                for m in range(n + 1, arm.n_segments)
            )
    return out


def motion_direction(
    new: np.ndarray, old: np.ndarray | None, last: np.ndarray, hold: bool, eps: float
) -> np.ndarray:
    """sgn of (new - old) element-wise; where |new - old| <= eps: the last sign if ``hold`` else 0
    (eq. 17: eta = 0 while theta_dot = 0). ``old`` None (first call): all 0."""
    if old is None:
        return np.zeros_like(np.asarray(new, dtype=float))
    diff = np.asarray(new, dtype=float) - np.asarray(old, dtype=float)
    sign = np.where(np.abs(diff) > eps, np.sign(diff), 0.0)
    if hold:
        sign = np.where(sign == 0.0, last, sign)
    return sign


def cable_friction_state(
    q_in_mm: np.ndarray, q_out_mm: np.ndarray, pull_mm: np.ndarray, release_mm: np.ndarray
) -> np.ndarray:
    """Where each cable is in its dead zone, sigma in [-1, 1] (the sign and share of the full
    sliding friction it carries): +1 sliding while pulled in (q_in - q_out = e_p), -1 while
    released (q_in - q_out = -e_r), linear in between (stick: the friction force builds up
    along the cable as the input crosses the dead zone, :func:`dead_zone_mm`). A cable with no
    dead zone: 0."""
    half = 0.5 * (np.asarray(pull_mm) + np.asarray(release_mm))
    mid = 0.5 * (np.asarray(pull_mm) - np.asarray(release_mm))
    lag = np.asarray(q_in_mm, dtype=float) - np.asarray(q_out_mm, dtype=float)
    safe = np.where(half > 0, half, 1.0)
    return np.where(half > 0, np.clip((lag - mid) / safe, -1.0, 1.0), 0.0)


def segment_friction_direction(arm: UJointArm, theta: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Per segment and coordinate, the direction of its cables' friction torque (N, 2) in
    [-1, 1], the continuous stand-in for sgn(theta_dot_m) of eq. 14/17.

    A cable k pulled in (q_dot > 0) moves the segment with J_k . theta_dot < 0 (its path
    shortens, J = :func:`segment_cable_jacobian`), so sliding along theta_dot_j > 0 gives
    sigma_k = -sgn(J_kj) for the cables that carry coordinate j, and
    s_j = -(J^T sigma)_j / sum_k |J_kj| = +1; sliding back gives -1; in between (cables in their
    dead zone) s moves smoothly; at rest after a move it keeps its value (static friction).
    """
    t = np.asarray(theta, dtype=float)
    out = np.zeros((arm.n_segments, 2))
    for n, holes in enumerate(arm.hole_sets):
        _, g, _ = _hole_terms(holes.own, t[n, 0], t[n, 1])  # g = J^T (2, K)
        norm = np.abs(g).sum(axis=1)
        out[n] = np.where(
            norm > 0, -(g @ sigma[holes.own.index]) / np.where(norm > 0, norm, 1.0), 0.0
        )
    return np.clip(out, -1.0, 1.0)
