"""Attitude samples: roll/pitch/yaw <-> rotation matrices in the sensor's own world frame.

Angles: roll about x, pitch about y, yaw about z, applied in the order Z-Y-X:
``R_world_sensor = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (pitch in [-90°, 90°]); the world frame has
z up (gravity along -z) and x at yaw 0. Yaw comes from the magnetometer or gyro integration and is
unreliable near steel structures (the paper avoids it); :meth:`AttitudeSample.rotation` can
leave it out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# -- orientation ----------------------------------------------------------------------------


def rotation_from_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """``R_world_sensor = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (angles in rad)."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rpy_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad of ``R = Rz(yaw) Ry(pitch) Rx(roll)``; pitch in [-π/2, π/2].

    At pitch = ±90° (gimbal lock) roll and yaw are not separable: roll is returned as 0.
    """
    m = np.asarray(R, dtype=float)
    pitch = math.asin(max(-1.0, min(1.0, -m[2, 0])))
    if abs(m[2, 0]) < 1.0 - 1e-12:
        roll = math.atan2(m[2, 1], m[2, 2])
        yaw = math.atan2(m[1, 0], m[0, 0])
    else:
        roll = 0.0
        yaw = math.atan2(-m[0, 1], m[1, 1])
    return roll, pitch, yaw


@dataclass(frozen=True, slots=True)
class Attitude:
    """One orientation report of a sensor (angles in rad, world frame z up).

    ``quaternion_wxyz``, ``acceleration_g``, ``angular_rate_dps``: the newest of those packets
    when the sensor sends them (sensor frame), else None.
    """

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    quaternion_wxyz: tuple[float, float, float, float] | None = None
    acceleration_g: tuple[float, float, float] | None = None
    angular_rate_dps: tuple[float, float, float] | None = None


@dataclass(frozen=True, slots=True)
class AttitudeSample:
    """The loop's view of one sensor: newest angles with time, age and health.

    ``index``: position in the config's ``sensors`` list (joint order, base first); ``port``:
    its serial port. Angles in rad (NaN before the first sample). ``t_s``: arrival time of the
    angle frame (s, reader clock); ``age_s``: now - t_s (inf when none); ``stale``: older than
    ``stale_after_s``, none yet, or the port failed. ``seq``: angle reports so far.
    """

    index: int
    port: str
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    quaternion_wxyz: tuple[float, float, float, float] | None
    t_s: float
    age_s: float
    stale: bool
    seq: int

    def rotation(self, use_yaw: bool = True) -> np.ndarray:
        """``R_world_sensor`` (3x3) from the angles; ``use_yaw=False`` sets yaw to 0.

        All-NaN before the first sample.
        """
        return rotation_from_rpy(self.roll_rad, self.pitch_rad, self.yaw_rad if use_yaw else 0.0)
