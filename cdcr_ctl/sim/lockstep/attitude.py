"""The simulated attitude sensors (vertebra arm) on the lock-step clock, through the real parser.

Each sensor's frames are made by :class:`~cdcr_ctl.sim.attitude.WitMotionFrames` (the bytes the
real-time simulator writes to its pty: acceleration, angular rate, angle, quaternion) every
``1/rate_hz`` s of simulated time from the truth's joint-end orientation, and handed
``latency_s`` later to the controller's :class:`~cdcr_ctl.sensors.attitude.WitMotionSensor`
(made by the production :func:`~cdcr_ctl.sensors.attitude.open_attitude_sensors`, its reader
thread not started: :meth:`AttitudeSchedule.advance` feeds it). The reader's clock is the
simulated one, so ages and staleness are in simulated time. A pty carries bytes at once, so no
wire time is added (as in real time).
"""

from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any

from cdcr_ctl.config.tracking import AttitudeSensorsConfig
from cdcr_ctl.control.io import AttitudeAngles
from cdcr_ctl.sensors.attitude import open_attitude_sensors
from cdcr_ctl.sim.attitude import WitMotionFrames
from cdcr_ctl.sim.lockstep.canlink import no_cpu_clock
from cdcr_ctl.sim.simconfig import AttitudeSimConfig


class QuietPort:
    """A pyserial-like port that never has bytes (``timeout``, ``in_waiting``, ``read``,
    ``close``): the lock-step schedule hands each frame to the reader with its arrival time."""

    def __init__(self, port: str, **_settings: Any) -> None:
        self.port = port
        self.timeout: float | None = None
        self.in_waiting = 0
        self.is_open = True

    def read(self, size: int = 1) -> bytes:
        return b""

    def close(self) -> None:
        self.is_open = False


class AttitudeSchedule:
    """Every sensor's frames every ``1/rate_hz`` s of simulated time, delivered ``latency_s``
    later to its reader (joint order)."""

    def __init__(self, frames: list[WitMotionFrames], readers: list[Any]) -> None:
        if len(frames) != len(readers):
            raise ValueError(f"{len(frames)} simulated sensors for {len(readers)} readers")
        self.frames = frames
        self.readers = readers
        self.next_s = [0.0] * len(frames)
        self._queues: list[collections.deque[tuple[float, bytes]]] = [
            collections.deque() for _ in frames
        ]
        self.cpu_s = 0.0
        self.cpu_clock: Callable[[], float] = no_cpu_clock  # time.thread_time to measure
        self.reports = 0

    def advance(self, t0: float, t1: float) -> None:
        """Frames sampled in (t0, t1] are made now (from the truth as stepped for this period);
        frames due by t1 are parsed with their arrival time."""
        c0 = self.cpu_clock()
        parts = zip(self.frames, self.readers, self._queues, strict=True)
        for k, (dev, reader, queue) in enumerate(parts):
            t = self.next_s[k]
            while t <= t1:
                queue.append((t + dev.latency_s, dev.frames_for(dev.truth(), t)))
                t += dev.period_s
            self.next_s[k] = t
            while queue and queue[0][0] <= t1:
                t_rx, data = queue.popleft()
                self.reports += reader.handle_bytes(data, t_rx)
        self.cpu_s += self.cpu_clock() - c0


def open_lockstep_attitude(
    cfg: AttitudeSensorsConfig,
    orientation: Callable[[int], Any],
    sim: AttitudeSimConfig,
    seed: int,
    clock: Callable[[], float],
) -> tuple[AttitudeSchedule, AttitudeAngles]:
    """The schedule and the controller's attitude port for the sensors of ``cfg`` (joint order):
    sensor ``i`` reads ``orientation(i)`` (R_world_sensor) with the noise of ``sim`` and seed
    ``seed + i`` (as the real-time simulator's)."""
    frames = [
        WitMotionFrames(
            lambda i=i: orientation(i),
            rate_hz=sim.rate_hz,
            noise_deg=sim.noise_deg,
            yaw_offset_deg=sim.yaw_offset_deg,
            latency_s=sim.latency_s,
            seed=seed + i,
        )
        for i in range(len(cfg.sensors))
    ]
    group = open_attitude_sensors(cfg, clock=clock, open_port=QuietPort, start=False)
    return AttitudeSchedule(frames, group.sensors), AttitudeAngles(group)


__all__ = ["AttitudeSchedule", "QuietPort", "open_lockstep_attitude"]
