"""WitMotion sensors on serial ports: one reader thread per sensor, all of the arm's from config.

The frames are :mod:`cdcr_ctl.sensors.attitude.witmotion`'s; the samples are
:mod:`cdcr_ctl.sensors.attitude.orientation`'s.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Sequence
from typing import Self, TypeVar

import serial

from cdcr_ctl.config.tracking import AttitudeSensorsConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.attitude.orientation import Attitude, AttitudeSample
from cdcr_ctl.sensors.attitude.witmotion import (
    WitAcceleration,
    WitAngle,
    WitAngularRate,
    WitMotionDecoder,
    WitQuaternion,
)
from cdcr_ctl.sensors.loadcell import LinkStats, TrafficLog
from cdcr_ctl.sensors.polling import PollingReader
from cdcr_ctl.sensors.sample import Clock, LatestValue

#: Longest single blocking read of the port (s): its read timeout, so ``stop()`` is prompt.
READ_POLL_S = 0.02


R = TypeVar("R")


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
