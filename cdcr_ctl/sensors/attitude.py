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
"""

from __future__ import annotations

import contextlib
import math
import struct
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Self, TypeVar

import numpy as np
import serial

from cdcr_ctl.config.tracking import AttitudeSensorsConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.loadcell import LinkStats, TrafficLog
from cdcr_ctl.sensors.polling import PollingReader
from cdcr_ctl.sensors.sample import Clock, LatestValue

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

#: Longest single blocking read of the port (s): its read timeout, so ``stop()`` is prompt.
READ_POLL_S = 0.02

_VALUES = struct.Struct("<4h")
R = TypeVar("R")


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


class WitMotionSensor(PollingReader):
    """One WitMotion sensor streaming on an injected pyserial ``port``.

    ``port``'s read timeout is set to :data:`READ_POLL_S`; :meth:`close` closes it.
    ``port_name`` names it in errors (default ``port.port``); ``index``: its joint index.
    Every angle frame publishes an :class:`Attitude` (with the newest quaternion, acceleration
    and angular rate seen before it). A failing port (unplugged, pty closed) raises
    :class:`SensorError` from :meth:`poll` and stops the thread.
    """

    def __init__(
        self,
        port: serial.SerialBase,
        *,
        port_name: str | None = None,
        index: int = 0,
        stale_after_s: float = 0.1,
        clock: Clock = time.monotonic,
    ) -> None:
        super().__init__()
        self.port = port
        self.port_name = port_name or str(getattr(port, "port", None) or port)
        self.index = index
        self.clock = clock
        self.stats = LinkStats()
        self.traffic = TrafficLog()
        self.decoder = WitMotionDecoder(self.stats)
        self.values: LatestValue[Attitude] = LatestValue(stale_after_s, clock)
        self._quaternion: tuple[float, float, float, float] | None = None
        self._acc: tuple[float, float, float] | None = None
        self._rate: tuple[float, float, float] | None = None
        self._io("configure", lambda: setattr(port, "timeout", READ_POLL_S))

    def poll(self) -> None:
        """Read what arrived (waiting at most :data:`READ_POLL_S`) and publish angle frames."""
        waiting = self._io("check", lambda: self.port.in_waiting)
        data = self._io("read", lambda: self.port.read(max(1, waiting)))
        if data:
            self.handle_bytes(data, self.clock())

    def handle_bytes(self, data: bytes, t_rx: float | None = None) -> int:
        """Decode bytes that arrived at ``t_rx`` (s, reader clock); returns angle reports made."""
        t = self.clock() if t_rx is None else t_rx
        self.traffic.add("rx", data, t)
        published = 0
        for p in self.decoder.feed(data):
            if isinstance(p, WitQuaternion):
                self._quaternion = (p.w, p.x, p.y, p.z)
            elif isinstance(p, WitAcceleration):
                self._acc = (p.x_g, p.y_g, p.z_g)
            elif isinstance(p, WitAngularRate):
                self._rate = (p.x_dps, p.y_dps, p.z_dps)
            elif isinstance(p, WitAngle):
                self.values.publish(
                    Attitude(
                        math.radians(p.roll_deg),
                        math.radians(p.pitch_deg),
                        math.radians(p.yaw_deg),
                        self._quaternion,
                        self._acc,
                        self._rate,
                    ),
                    t,
                )
                published += 1
        return published

    def latest(self, now_s: float | None = None) -> AttitudeSample:
        """Newest angles aged at ``now_s`` (s; default now). Never blocks on the port."""
        got = self.values.latest(now_s)
        a = got.value
        stale = got.stale or self.failure is not None
        if a is None:
            nan = math.nan
            return AttitudeSample(
                self.index, self.port_name, nan, nan, nan, None, got.t_s, got.age_s, True, 0
            )
        return AttitudeSample(
            self.index,
            self.port_name,
            a.roll_rad,
            a.pitch_rad,
            a.yaw_rad,
            a.quaternion_wxyz,
            got.t_s,
            got.age_s,
            stale,
            got.seq,
        )

    def _on_failure(self, exc: SensorError) -> None:
        self.values.invalidate()

    def _close_transport(self) -> None:
        with contextlib.suppress(serial.SerialException, OSError):
            self.port.close()

    def _io(self, doing: str, call: Callable[[], R]) -> R:
        try:
            return call()
        except (serial.SerialException, OSError, ValueError, TypeError) as exc:
            raise SensorError(
                self.port_name,
                f"serial port failed during {doing} (disconnected?): {exc}\n"
                f"last data:\n{self.traffic.dump()}",
            ) from exc


class AttitudeSensors:
    """All attitude sensors of the arm, in joint order; each runs its own reader thread.

    :meth:`latest` gives one :class:`AttitudeSample` per sensor; :attr:`failure` the first
    sensor failure. A context manager: leaving it stops the threads and closes the ports.
    """

    def __init__(self, sensors: Sequence[WitMotionSensor]) -> None:
        if not sensors:
            raise ValueError("no attitude sensors")
        self.sensors = list(sensors)

    @property
    def failure(self) -> SensorError | None:
        """The first failure of any sensor, or None."""
        return next((s.failure for s in self.sensors if s.failure is not None), None)

    def raise_if_failed(self) -> None:
        """Raise :attr:`failure` if there is one."""
        failure = self.failure
        if failure is not None:
            raise failure

    def latest(self, now_s: float | None = None) -> tuple[AttitudeSample, ...]:
        """Newest sample of every sensor, in joint order. Never blocks."""
        return tuple(s.latest(now_s) for s in self.sensors)

    def wait_for_samples(self, timeout_s: float = 1.0) -> None:
        """Block until every sensor has a sample (start-up only); SensorError names the silent."""
        deadline = time.monotonic() + timeout_s
        while True:
            self.raise_if_failed()
            missing = [s.port_name for s in self.sensors if s.values.stamped is None]
            if not missing:
                return
            if time.monotonic() >= deadline:
                raise SensorError(missing[0], f"no angle frame within {timeout_s} s")
            time.sleep(0.005)

    def start(self) -> Self:
        for s in self.sensors:
            s.start()
        return self

    def close(self) -> None:
        for s in self.sensors:
            s.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_attitude_sensors(
    cfg: AttitudeSensorsConfig,
    *,
    clock: Clock = time.monotonic,
    open_port: Callable[..., serial.SerialBase] = serial.serial_for_url,
    start: bool = True,
) -> AttitudeSensors:
    """Open every port of ``cfg`` (8 data bits, its baud/parity/stop bits), make the readers,
    and (``start``) start them. SensorError names a port that cannot be opened (those already
    opened are closed again)."""
    sensors: list[WitMotionSensor] = []
    try:
        for i, pc in enumerate(cfg.sensors):
            try:
                port = open_port(
                    pc.port,
                    baudrate=pc.baudrate,
                    parity=pc.parity,
                    stopbits=pc.stopbits,
                    timeout=READ_POLL_S,
                )
            except (serial.SerialException, OSError, ValueError) as exc:
                raise SensorError(pc.port, f"cannot open attitude sensor {i}: {exc}") from exc
            sensors.append(
                WitMotionSensor(
                    port,
                    port_name=pc.port,
                    index=i,
                    stale_after_s=cfg.stale_after_s,
                    clock=clock,
                )
            )
    except BaseException:
        for s in sensors:
            s.close()
        raise
    group = AttitudeSensors(sensors)
    return group.start() if start else group
