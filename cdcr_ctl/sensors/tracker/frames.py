"""Tracker frames: rotations (rotation vector, quaternion) and the tracker -> robot base transform.

Pure numpy, no I/O. The tracker reports the rigid body's pose in its own frame and units:
position ``p_b`` (units) and rotation ``R_tb`` (body -> tracker). With ``s`` = mm per unit,
``(R_mb, t_mb)`` = ``marker_to_tip`` (tip frame -> body frame, mm) and ``(R_bt, t_bt)`` =
``base_from_tracker`` (tracker frame -> base frame, mm)::

    p_tip_tracker_mm = s * p_b + R_tb @ t_mb
    p_tip_base_mm    = R_bt @ p_tip_tracker_mm + t_bt
    R_base_tip       = R_bt @ R_tb @ R_mb
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.config.tracking import RigidTransformConfig, TrackerConfig

#: Unit quaternions must have a norm within this of 1 (float32 rounding is ~1e-7).
QUATERNION_NORM_TOL = 1e-3


# -- rotations ------------------------------------------------------------------------------


def rotation_from_rotvec(rotvec: np.ndarray | list[float]) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis * angle, rad), by Rodrigues' formula."""
    v = np.asarray(rotvec, dtype=float)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.eye(3)
    k = v / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def rotation_from_quaternion(q_xyzw: np.ndarray | tuple[float, ...]) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w; scalar last), normalised first.

    ValueError when the norm is not within :data:`QUATERNION_NORM_TOL` of 1 or not finite.
    """
    return np.array(rotation_rows(q_xyzw))


def rotation_rows(q_xyzw: np.ndarray | tuple[float, ...]) -> list[list[float]]:
    """:func:`rotation_from_quaternion` as three rows of Python floats (the same doubles)."""
    q = np.asarray(q_xyzw, dtype=float)
    n = _norm(q)
    if not (math.isfinite(n) and abs(n - 1.0) <= QUATERNION_NORM_TOL):
        raise ValueError(f"not a unit quaternion (norm {n})")
    # Python floats: the same doubles (IEEE division either way), cheaper arithmetic
    x, y, z, w = [v / n for v in q.tolist()]
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w; w >= 0) of a rotation matrix (Shepperd's method)."""
    return np.array(quaternion_xyzw(np.asarray(R, dtype=float).tolist()))


def quaternion_xyzw(rows: list[list[float]]) -> list[float]:
    """:func:`quaternion_from_rotation` of a matrix given as three rows of Python floats, as
    Python floats (the same doubles)."""
    # The nine entries as Python floats (numpy's per-element indexing costs more than the
    # arithmetic).
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = rows
    tr = m00 + m11 + m22
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [(m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, s / 4]
    elif m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = [s / 4, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s]
    elif m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = [(m01 + m10) / s, s / 4, (m12 + m21) / s, (m02 - m20) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = [(m02 + m20) / s, (m12 + m21) / s, s / 4, (m10 - m01) / s]
    n = _norm(np.array(q))
    out = [v / n for v in q]  # numpy's array / norm: the same IEEE divisions
    return [-v for v in out] if out[3] < 0 else out


def _norm(v: np.ndarray) -> float:
    """``float(np.linalg.norm(v))`` of a float64 vector, computed as numpy computes it (the
    square root of ``v.dot(v)``) without its dispatch."""
    return math.sqrt(v.dot(v))


# -- frames ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrackerTransform:
    """Tracker-frame body pose -> tip in the robot base frame (see the module docstring).

    ``R_base_tracker``, ``t_base_tracker_mm``: base_from_tracker; ``R_body_tip``,
    ``t_body_tip_mm``: marker_to_tip (the tip in the body frame); ``mm_per_unit``: tracker scale.
    """

    R_base_tracker: np.ndarray
    t_base_tracker_mm: np.ndarray
    R_body_tip: np.ndarray
    t_body_tip_mm: np.ndarray
    mm_per_unit: float

    @classmethod
    def identity(cls, mm_per_unit: float = 1.0) -> TrackerTransform:
        """No alignment, tip at the body origin."""
        return cls(np.eye(3), np.zeros(3), np.eye(3), np.zeros(3), mm_per_unit)

    @classmethod
    def from_transforms(
        cls,
        base_from_tracker: RigidTransformConfig,
        marker_to_tip: RigidTransformConfig,
        mm_per_unit: float,
    ) -> TrackerTransform:
        """From the two config transforms (rotation vectors in rad, translations in mm)."""
        return cls(
            rotation_from_rotvec(base_from_tracker.rotvec_rad),
            np.asarray(base_from_tracker.translation_mm, dtype=float),
            rotation_from_rotvec(marker_to_tip.rotvec_rad),
            np.asarray(marker_to_tip.translation_mm, dtype=float),
            float(mm_per_unit),
        )

    @classmethod
    def from_config(cls, cfg: TrackerConfig) -> TrackerTransform:
        """From a tracker config section."""
        return cls.from_transforms(cfg.base_from_tracker, cfg.marker_to_tip, cfg.mm_per_unit)

    def tip_in_base(
        self, position_units: np.ndarray | tuple[float, ...], R_tracker_body: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(tip position in the base frame (mm), R_base_tip) for a body pose in tracker units."""
        p_tracker_mm = self.mm_per_unit * np.asarray(position_units, dtype=float)
        p_tracker_mm = p_tracker_mm + R_tracker_body @ self.t_body_tip_mm
        p_base = self.R_base_tracker @ p_tracker_mm + self.t_base_tracker_mm
        return p_base, self.R_base_tracker @ R_tracker_body @ self.R_body_tip

    def body_in_tracker(
        self, p_tip_base_mm: np.ndarray, R_base_tip: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`tip_in_base`: (body position in tracker units, R_tracker_body)."""
        R_tb = self.R_base_tracker.T @ np.asarray(R_base_tip, dtype=float) @ self.R_body_tip.T
        p_tracker_mm = self.R_base_tracker.T @ (
            np.asarray(p_tip_base_mm, dtype=float) - self.t_base_tracker_mm
        )
        return (p_tracker_mm - R_tb @ self.t_body_tip_mm) / self.mm_per_unit, R_tb

    def body_in_tracker_floats(
        self, p_tip_base_mm: np.ndarray, R_base_tip: np.ndarray
    ) -> tuple[list[float], list[list[float]]]:
        """:meth:`body_in_tracker` as Python floats (the same doubles): the position and the
        three rows of R_tracker_body."""
        p, R = self.body_in_tracker(p_tip_base_mm, R_base_tip)
        return p.tolist(), R.tolist()
