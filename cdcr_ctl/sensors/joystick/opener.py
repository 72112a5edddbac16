"""The joystick from config: a network joystick for ``tcp://`` devices, evdev otherwise."""

from __future__ import annotations

import time

from cdcr_ctl.config.tracking import JoystickConfig
from cdcr_ctl.sensors.joystick.evdev_device import open_evdev_joystick
from cdcr_ctl.sensors.joystick.network import open_tcp_joystick
from cdcr_ctl.sensors.joystick.reader import Joystick
from cdcr_ctl.sensors.sample import Clock


def open_joystick(
    cfg: JoystickConfig, *, clock: Clock = time.monotonic, start: bool = True
) -> Joystick:
    """The joystick of ``cfg``: a network joystick for ``tcp://`` devices, evdev otherwise."""
    if cfg.tcp_address is not None:
        return open_tcp_joystick(cfg, clock=clock, start=start)
    return open_evdev_joystick(cfg, clock=clock, start=start)
