"""WitMotion standard-protocol frames (pure bytes): pack, decode, resynchronise on garbage.

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

The decoder resynchronises on garbage: it looks for 0x55 followed by a type byte 0x50-0x5F, and a
frame whose checksum fails costs only its first byte, so a real frame starting inside it is found.
Bad frames are counted and never returned.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from cdcr_ctl.sensors.loadcell import LinkStats

HEADER = 0x55
FRAME_BYTES = 11
TYPE_ACCELERATION = 0x51
TYPE_ANGULAR_RATE = 0x52
TYPE_ANGLE = 0x53
TYPE_QUATERNION = 0x59
#: Type bytes of the standard protocol (0x50-0x5F); anything else after 0x55 is not a header.
VALID_TYPES = range(0x50, 0x60)

#: Full scales of the int16 fields (value = raw / 32768 * scale).
ACCELERATION_FULL_SCALE_G = 16.0
ANGULAR_RATE_FULL_SCALE_DPS = 2000.0
ANGLE_FULL_SCALE_DEG = 180.0


_VALUES = struct.Struct("<4h")


# -- frames ---------------------------------------------------------------------------------


def checksum(data: bytes) -> int:
    """WitMotion checksum of the first 10 bytes of a frame: the low byte of their sum."""
    return sum(data[:10]) & 0xFF


def pack_frame(kind: int, values: Sequence[int]) -> bytes:
    """A frame of ``kind`` carrying four int16 ``values`` (clamped to the int16 range)."""
    if not 0 <= kind <= 0xFF:
        raise ValueError(f"frame type {kind} is not a byte")
    clamped = [max(-32768, min(32767, int(v))) for v in values]
    body = bytes([HEADER, kind]) + _VALUES.pack(*clamped)
    return body + bytes([checksum(body)])


def _raw(value: float, full_scale: float) -> int:
    return max(-32768, min(32767, round(value / full_scale * 32768.0)))


def wrap_deg(angle_deg: float) -> float:
    """``angle_deg`` wrapped into [-180, 180) (°)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def pack_angle(roll_deg: float, pitch_deg: float, yaw_deg: float, aux: int = 0) -> bytes:
    """0x53 angle frame; angles (°) are wrapped into [-180, 180) first (+180 reads as -180)."""
    vals = [_raw(wrap_deg(a), ANGLE_FULL_SCALE_DEG) for a in (roll_deg, pitch_deg, yaw_deg)]
    return pack_frame(TYPE_ANGLE, [*vals, aux])


def pack_acceleration(acc_g: Sequence[float], temperature_C: float = 25.0) -> bytes:
    """0x51 acceleration frame: x, y, z (g), temperature (°C)."""
    vals = [_raw(a, ACCELERATION_FULL_SCALE_G) for a in acc_g]
    return pack_frame(TYPE_ACCELERATION, [*vals, round(temperature_C * 100.0)])


def pack_angular_rate(rate_dps: Sequence[float], aux: int = 0) -> bytes:
    """0x52 angular-rate frame: x, y, z (°/s)."""
    vals = [_raw(w, ANGULAR_RATE_FULL_SCALE_DPS) for w in rate_dps]
    return pack_frame(TYPE_ANGULAR_RATE, [*vals, aux])


def pack_quaternion(q_wxyz: Sequence[float]) -> bytes:
    """0x59 quaternion frame: w, x, y, z (unit quaternion, scalar first)."""
    return pack_frame(TYPE_QUATERNION, [_raw(c, 1.0) for c in q_wxyz])


@dataclass(frozen=True, slots=True)
class WitAngle:
    """0x53: roll, pitch, yaw (°) and the fourth field raw (version or temperature)."""

    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    aux: int


@dataclass(frozen=True, slots=True)
class WitAcceleration:
    """0x51: acceleration x, y, z (g, sensor frame) and temperature (°C)."""

    x_g: float
    y_g: float
    z_g: float
    temperature_C: float


@dataclass(frozen=True, slots=True)
class WitAngularRate:
    """0x52: angular rate about x, y, z (°/s, sensor frame); fourth field raw."""

    x_dps: float
    y_dps: float
    z_dps: float
    aux: int


@dataclass(frozen=True, slots=True)
class WitQuaternion:
    """0x59: orientation quaternion w, x, y, z (as sent; norm ~1 within int16 rounding)."""

    w: float
    x: float
    y: float
    z: float


@dataclass(frozen=True, slots=True)
class WitOther:
    """A checksum-valid frame of a type this module does not decode (time, magnetic, ...)."""

    kind: int
    payload: bytes


WitPacket = WitAngle | WitAcceleration | WitAngularRate | WitQuaternion | WitOther


def decode_frame(frame: bytes) -> WitPacket:
    """One 11-byte frame whose header and checksum were checked, as a packet."""
    kind = frame[1]
    v = _VALUES.unpack_from(frame, 2)
    if kind == TYPE_ANGLE:
        return WitAngle(*(x / 32768.0 * ANGLE_FULL_SCALE_DEG for x in v[:3]), v[3])
    if kind == TYPE_ACCELERATION:
        return WitAcceleration(
            *(x / 32768.0 * ACCELERATION_FULL_SCALE_G for x in v[:3]), v[3] / 100
        )
    if kind == TYPE_ANGULAR_RATE:
        return WitAngularRate(*(x / 32768.0 * ANGULAR_RATE_FULL_SCALE_DPS for x in v[:3]), v[3])
    if kind == TYPE_QUATERNION:
        return WitQuaternion(*(x / 32768.0 for x in v))
    return WitOther(kind, bytes(frame[2:10]))


class WitMotionDecoder:
    """Incremental frame decoder: feed bytes in any chunks, get the packets of complete frames.

    ``stats``: ``frames_ok`` (packets returned), ``bad_frames`` (header found, checksum wrong),
    ``discarded_bytes`` (bytes skipped while resynchronising).
    """

    def __init__(self, stats: LinkStats | None = None) -> None:
        self.stats = stats if stats is not None else LinkStats()
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[WitPacket]:
        """Decode ``data``; return the packets it completed, oldest first. Never raises."""
        buf = self._buf
        buf += data
        out: list[WitPacket] = []
        while buf:
            start = buf.find(HEADER)
            if start < 0:
                self._discard(len(buf))
                break
            if start:
                self._discard(start)
            if len(buf) >= 2 and buf[1] not in VALID_TYPES:
                self._discard(1)
                continue
            if len(buf) < FRAME_BYTES:
                break
            frame = bytes(buf[:FRAME_BYTES])
            if checksum(frame) != frame[10]:
                self.stats.bad_frames += 1
                self._discard(1)
                continue
            del buf[:FRAME_BYTES]
            self.stats.frames_ok += 1
            out.append(decode_frame(frame))
        return out

    def _discard(self, n: int) -> None:
        del self._buf[:n]
        self.stats.discarded_bytes += n
