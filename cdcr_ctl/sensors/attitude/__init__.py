"""WitMotion JY901/WT901 attitude sensors over serial: frames, resync, orientation samples.

One sensor sits at the end of each joint of the vertebra arm (fuel-tank paper, Fig. 6). This module
only reports what each sensor says, as roll/pitch/yaw and rotation matrices in the sensor's own
world frame; turning pairs of them into a joint's bend (θ, φ) from ``R_{i-1}^T R_i`` (paper eq.
6-8) is the robot model's job (``cdcr_ctl.model.vertebra``).

Protocol (WitMotion "standard protocol", the sensor streams unsolicited at its set rate)::

    0x55, type, d0 d1 d2 d3 d4 d5 d6 d7, checksum        (11 bytes)
    checksum = (sum of the first 10 bytes) & 0xFF
    d = four little-endian int16 values v0..v3

    0x51 acceleration:   v0..v2 / 32768 * 16 g,          v3 / 100 = temperature (°C)
    0x52 angular rate:   v0..v2 / 32768 * 2000 °/s,      v3 (voltage or temperature, raw)
    0x53 angle:          roll, pitch, yaw = v0..v2 / 32768 * 180 °, v3 (firmware version on
                         current models, temperature * 100 on old ones; raw)
    0x59 quaternion:     q0 (w), q1, q2, q3 = v0..v3 / 32768
    other types (0x50 time, 0x54 magnetic field, 0x55 port status, ...) are checked and skipped

Angles: roll about x, pitch about y, yaw about z, applied in the order Z-Y-X:
``R_world_sensor = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (pitch in [-90°, 90°]); the world frame has
z up (gravity along -z) and x at yaw 0. Yaw comes from the magnetometer or gyro integration and is
unreliable near steel structures (the paper avoids it); :meth:`AttitudeSample.rotation` can
leave it out.

The decoder resynchronises on garbage: it looks for 0x55 followed by a type byte 0x50-0x5F, and a
frame whose checksum fails costs only its first byte, so a real frame starting inside it is found.
Bad frames are counted and never returned.

This package re-exports every name of the former ``sensors/attitude.py``. Its rooms:
:mod:`~cdcr_ctl.sensors.attitude.witmotion` (frames and the decoder, pure bytes),
:mod:`~cdcr_ctl.sensors.attitude.orientation` (angles <-> rotations, samples) and
:mod:`~cdcr_ctl.sensors.attitude.reader` (serial readers, :func:`open_attitude_sensors`).
"""

from cdcr_ctl.sensors.attitude.orientation import (
    Attitude,
    AttitudeSample,
    rotation_from_rpy,
    rpy_from_rotation,
)
from cdcr_ctl.sensors.attitude.reader import (
    READ_POLL_S,
    AttitudeSensors,
    WitMotionSensor,
    open_attitude_sensors,
)
from cdcr_ctl.sensors.attitude.witmotion import (
    ACCELERATION_FULL_SCALE_G,
    ANGLE_FULL_SCALE_DEG,
    ANGULAR_RATE_FULL_SCALE_DPS,
    FRAME_BYTES,
    HEADER,
    TYPE_ACCELERATION,
    TYPE_ANGLE,
    TYPE_ANGULAR_RATE,
    TYPE_QUATERNION,
    VALID_TYPES,
    WitAcceleration,
    WitAngle,
    WitAngularRate,
    WitMotionDecoder,
    WitOther,
    WitPacket,
    WitQuaternion,
    checksum,
    decode_frame,
    pack_acceleration,
    pack_angle,
    pack_angular_rate,
    pack_frame,
    pack_quaternion,
    wrap_deg,
)

__all__ = [
    "ACCELERATION_FULL_SCALE_G",
    "ANGLE_FULL_SCALE_DEG",
    "ANGULAR_RATE_FULL_SCALE_DPS",
    "FRAME_BYTES",
    "HEADER",
    "READ_POLL_S",
    "TYPE_ACCELERATION",
    "TYPE_ANGLE",
    "TYPE_ANGULAR_RATE",
    "TYPE_QUATERNION",
    "VALID_TYPES",
    "Attitude",
    "AttitudeSample",
    "AttitudeSensors",
    "WitAcceleration",
    "WitAngle",
    "WitAngularRate",
    "WitMotionDecoder",
    "WitMotionSensor",
    "WitOther",
    "WitPacket",
    "WitQuaternion",
    "checksum",
    "decode_frame",
    "open_attitude_sensors",
    "pack_acceleration",
    "pack_angle",
    "pack_angular_rate",
    "pack_frame",
    "pack_quaternion",
    "rotation_from_rpy",
    "rpy_from_rotation",
    "wrap_deg",
]
