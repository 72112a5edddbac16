"""Simulated WitMotion attitude sensors on pseudo-terminals, driven by truth orientations.

Each :class:`SimWitMotion` owns a pty: the controller opens :attr:`SimWitMotion.path` like the
sensor's USB serial port and receives the standard-protocol frames (see
:mod:`cdcr_ctl.sensors.attitude`) for the truth orientation ``R_world_sensor`` at ``rate_hz``:
acceleration (gravity seen in the sensor frame), angular rate (from successive orientations),
angle and quaternion. Options add angle noise, a yaw offset (a magnetometer disturbed by the
structure) and a fixed latency.

A pty carries bytes at once (no baud-rate timing). Writes never block: when nobody reads and the
pty's buffer is full the frames are dropped and counted in :attr:`SimWitMotion.overruns`, like a
UART overrun. Fault hooks: :meth:`inject` (raw bytes: garbage, a frame with a bad checksum),
:meth:`pause`/:meth:`resume`, :meth:`hang_up` (close the pty: the reader's next read fails).
"""

from __future__ import annotations

import collections
import contextlib
import errno
import fcntl
import logging
import math
import os
import threading
import time
import tty
from collections.abc import Callable, Sequence
from typing import Any, Self

import numpy as np

from cdcr_ctl.sensors.attitude import (
    pack_acceleration,
    pack_angle,
    pack_angular_rate,
    pack_quaternion,
    rpy_from_rotation,
)
from cdcr_ctl.sensors.tracker import quaternion_from_rotation

log = logging.getLogger(__name__)

#: Frame kinds a simulated sensor can send, in the order it sends them each cycle.
PACKETS = ("acceleration", "angular_rate", "angle", "quaternion")


def rotvec_from_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle, rad) of a rotation matrix (angles below π)."""
    m = np.asarray(R, dtype=float)
    cos_angle = max(-1.0, min(1.0, (m[0, 0] + m[1, 1] + m[2, 2] - 1.0) / 2.0))
    angle = math.acos(cos_angle)
    w = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    if angle < 1e-9:
        return w / 2.0
    return w * (angle / (2.0 * math.sin(angle)))


class WitMotionFrames:
    """The frames of a simulated WitMotion JY901/WT901 (no port: :class:`SimWitMotion` writes
    them to a pty, the lock-step rig hands them to the reader on simulated time).

    ``truth()``: the sensor's orientation now, ``R_world_sensor`` (3x3, world z up).
    ``rate_hz``: output rate. ``noise_deg``: standard deviation of Gaussian noise on each angle
    (°). ``yaw_offset_deg``: constant error added to yaw (°). ``latency_s``: delay from sampling
    to writing. ``packets``: which frames to send, from :data:`PACKETS`. ``aux``: the angle
    frame's fourth field (firmware version). ``seed``: noise generator seed.
    """

    def __init__(
        self,
        truth: Callable[[], np.ndarray],
        *,
        rate_hz: float = 100.0,
        noise_deg: float = 0.0,
        yaw_offset_deg: float = 0.0,
        latency_s: float = 0.0,
        packets: Sequence[str] = PACKETS,
        aux: int = 0x1234,
        seed: int = 1,
    ) -> None:
        unknown = set(packets) - set(PACKETS)
        if unknown or not rate_hz > 0 or latency_s < 0:
            raise ValueError(f"bad sim sensor settings (unknown packets {sorted(unknown)})")
        self.truth = truth
        self.period_s = 1.0 / rate_hz
        self.noise_deg = float(noise_deg)
        self.yaw_offset_deg = float(yaw_offset_deg)
        self.latency_s = float(latency_s)
        self.packets = tuple(p for p in PACKETS if p in packets)
        self.aux = aux
        self.rng = np.random.default_rng(seed)
        self._prev: tuple[float, np.ndarray] | None = None

    # -- frames -----------------------------------------------------------------------------

    def frames_for(self, R_world_sensor: np.ndarray, now: float) -> bytes:
        """The bytes of one output cycle for orientation ``R_world_sensor`` at time ``now`` (s)."""
        R = np.asarray(R_world_sensor, dtype=float)
        out = b""
        if "acceleration" in self.packets:
            g_sensor = R.T @ np.array([0.0, 0.0, 1.0])  # at rest the sensor reads +1 g "up"
            out += pack_acceleration(g_sensor)
        if "angular_rate" in self.packets:
            rate = np.zeros(3)
            if self._prev is not None and now > self._prev[0]:
                dt = now - self._prev[0]
                rate = np.degrees(rotvec_from_rotation(self._prev[1].T @ R)) / dt
            out += pack_angular_rate(rate)
        self._prev = (now, R)
        roll, pitch, yaw = (math.degrees(a) for a in rpy_from_rotation(R))
        if self.noise_deg > 0:
            roll, pitch, yaw = (
                a + self.rng.normal(0.0, self.noise_deg) for a in (roll, pitch, yaw)
            )
        yaw += self.yaw_offset_deg
        if "angle" in self.packets:
            out += pack_angle(roll, pitch, yaw, self.aux)
        if "quaternion" in self.packets:
            x, y, z, w = quaternion_from_rotation(R)
            out += pack_quaternion((w, x, y, z))
        return out


class SimWitMotion(WitMotionFrames):
    """A simulated WitMotion JY901/WT901 on a fresh pty, sending :class:`WitMotionFrames`'
    frames (same arguments) at ``rate_hz`` from a thread of its own."""

    def __init__(self, truth: Callable[[], np.ndarray], **settings: Any) -> None:
        super().__init__(truth, **settings)
        self.master_fd, self.slave_fd = os.openpty()
        tty.setraw(self.slave_fd)
        tty.setraw(self.master_fd)
        flags = fcntl.fcntl(self.master_fd, fcntl.F_GETFL)
        fcntl.fcntl(self.master_fd, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self.path = os.ttyname(self.slave_fd)
        self.cycles = 0
        self.overruns = 0
        self.truth_errors = 0
        self._queue: collections.deque[tuple[float, bytes]] = collections.deque()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._paused = threading.Event()
        self._hung_up = False
        self._thread: threading.Thread | None = None

    # -- fault hooks ------------------------------------------------------------------------

    def inject(self, data: bytes) -> None:
        """Write raw ``data`` to the port now (garbage, split or corrupted frames)."""
        with self._lock:
            self._write(data)

    def pause(self) -> None:
        """Stop sending until :meth:`resume` (a sensor that went quiet)."""
        self._paused.set()

    def resume(self) -> None:
        self._paused.clear()

    def hang_up(self) -> None:
        """Close the pty (both ends we hold), like pulling the USB cable."""
        with self._lock:
            if self._hung_up:
                return
            self._hung_up = True
            for fd in (self.master_fd, self.slave_fd):
                with contextlib.suppress(OSError):
                    os.close(fd)

    # -- life cycle -------------------------------------------------------------------------

    def start(self) -> Self:
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._run, name=f"sim wit {self.path}", daemon=True
            )
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def close(self) -> None:
        self.stop()
        self.hang_up()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _run(self) -> None:
        next_tick = time.monotonic()
        while not self._stop.is_set() and not self._hung_up:
            now = time.monotonic()
            due = self._queue[0][0] if self._queue else math.inf
            if self._stop.wait(max(0.0, min(next_tick, due) - now)):
                return
            now = time.monotonic()
            if now >= next_tick:
                if not self._paused.is_set():
                    try:
                        data = self.frames_for(self.truth(), now)
                    except Exception:
                        self.truth_errors += 1
                        log.exception("sim attitude %s: truth failed", self.path)
                    else:
                        self._queue.append((now + self.latency_s, data))
                        self.cycles += 1
                next_tick += self.period_s
                if next_tick < now:
                    next_tick = now + self.period_s
            while self._queue and self._queue[0][0] <= now:
                _, data = self._queue.popleft()
                with self._lock:
                    if not self._paused.is_set():
                        self._write(data)

    def _write(self, data: bytes) -> None:
        if self._hung_up:
            return
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self.master_fd, view) :]
        except BlockingIOError:
            self.overruns += 1
        except OSError as exc:
            if exc.errno not in (errno.EIO, errno.EBADF):
                raise
            self.overruns += 1
