"""The simulated network joystick (vertebra arm) on the lock-step clock, through the real reader.

A ``joystick`` session opens the stick with the production
:func:`~cdcr_ctl.sensors.joystick.network.open_tcp_joystick` over one end of a TCP connection on
127.0.0.1 (its reader thread not started); the other end is the simulated sender. The simulator
config's stick script (:func:`cdcr_ctl.sim.rig.stick_script`, times from the connection) is played
on simulated time: each keyframe's ``struct input_event`` records (built by the same encoder as the
real-time simulator's :class:`~cdcr_ctl.sim.joystick.ScriptedJoystick`) are written when the
keyframe is due and read at once by the reader's own parser (:meth:`JoystickSchedule.advance` polls
it once per record, so it never waits on the wall clock). A ``disconnect_after_s`` closes the
sender's end at that time: the reader's next poll finds the connection closed and fails, as in real
time.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable
from typing import Any

from cdcr_ctl.config.tracking import JoystickConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.joystick import DEFAULT_RANGE, config_axis_range
from cdcr_ctl.sensors.joystick.input_event import pack_input_event
from cdcr_ctl.sensors.joystick.network import open_tcp_joystick
from cdcr_ctl.sim.joystick import JoystickFrame, ScriptedJoystick
from cdcr_ctl.sim.rig import stick_script
from cdcr_ctl.sim.simconfig import LoadedSim


def _loopback_pair() -> tuple[socket.socket, socket.socket]:
    """(sender, reader): the two ends of a TCP connection on 127.0.0.1 (the reader sets TCP
    keep-alive options, which a Unix socket pair does not have)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        reader = socket.create_connection(server.getsockname())
        try:
            sender, _ = server.accept()
        except BaseException:
            reader.close()
            raise
    return sender, reader


class _Playing:
    """One connection: the reader, the sender's socket and the keyframes still to send."""

    def __init__(
        self, stick: Any, sender: socket.socket, reader: socket.socket, t0_s: float, frames: list
    ) -> None:
        self.stick = stick
        self.sender = sender
        self.reader = reader
        self.t0_s = t0_s
        self.frames = frames
        self.next = 0


class JoystickSchedule:
    """Plays the stick script of ``loaded`` to each joystick opened with :meth:`open`, on the
    simulated ``clock``; :meth:`advance` delivers what is due."""

    def __init__(self, loaded: LoadedSim, clock: Callable[[], float]) -> None:
        js = loaded.rig.sensors.joystick
        if js is None:
            raise ValueError(f"{loaded.path}: the simulated rig has no joystick")
        sx = -1.0 if js.invert_x else 1.0
        sy = -1.0 if js.invert_y else 1.0
        frames = [JoystickFrame(f.t_s, sx * f.x, sy * f.y, f.buttons) for f in stick_script(loaded)]
        # The real-time simulator's encoder (the configured axes and raw range).
        self._encoder = ScriptedJoystick(
            frames,
            axis_x=js.axis_x,
            axis_y=js.axis_y,
            axis_range=config_axis_range(js) or DEFAULT_RANGE,
        ).encoder
        self.frames = frames
        self.disconnect_after_s = loaded.sim.joystick.disconnect_after_s
        self.clock = clock
        self._lock = threading.Lock()
        self._playing: _Playing | None = None
        self.records = 0

    def open(self, cfg: JoystickConfig) -> Any:
        """The daemon's joystick opener: the production reader on a new connection whose
        script starts now (simulated time)."""
        mine, theirs = _loopback_pair()
        try:
            stick = open_tcp_joystick(cfg, clock=self.clock, start=False, sock=theirs)
        except BaseException:
            mine.close()
            theirs.close()
            raise
        with self._lock:
            if self._playing is not None:
                self._playing.sender.close()
            self._playing = _Playing(stick, mine, theirs, self.clock(), list(self.frames))
        return stick

    def advance(self, t0: float, t1: float) -> None:
        """Send the keyframes due by ``t1`` and let the reader parse them; hang up at the
        disconnect time."""
        with self._lock:
            p = self._playing
            if p is not None and p.reader.fileno() == -1:  # the session closed the reader
                p.sender.close()
                self._playing = p = None
            if p is None:
                return
            sent = 0
            try:
                while p.next < len(p.frames) and p.t0_s + p.frames[p.next].t_s <= t1:
                    f = p.frames[p.next]
                    t = p.t0_s + f.t_s
                    for event in self._encoder.events(f.x, f.y, f.buttons):
                        p.sender.sendall(pack_input_event(*event, t_s=t))
                        sent += 1
                    p.next += 1
                cut = self.disconnect_after_s
                hang_up = cut is not None and p.t0_s + cut <= t1
                if hang_up:
                    p.sender.close()
            except OSError:  # the session closed the reader (its end is gone)
                self._playing = None
                return
            self.records += sent
            try:
                for _ in range(sent + (1 if hang_up else 0)):
                    p.stick.poll()  # one record each; the hang-up: reads the end of stream
            except SensorError as exc:
                p.stick._fail(exc)  # what the reader's thread does on a failure
                self._playing = None

    def close(self) -> None:
        with self._lock:
            if self._playing is not None:
                with contextlib.suppress(OSError):
                    self._playing.sender.close()
                self._playing = None


__all__ = ["JoystickSchedule"]
