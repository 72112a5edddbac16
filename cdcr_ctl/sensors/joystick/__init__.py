"""Joystick through Linux evdev: normalised axes in [-1, 1] with a deadband, and buttons.

The reader consumes an *event source*: any iterable of ``(type, code, value)`` tuples in evdev's
terms (``EV_ABS`` axis moves, ``EV_KEY`` button presses, ``EV_SYN`` reports), which may also yield
``None`` as an idle tick (lets the thread notice ``stop()``). Tests and the simulated rig inject a
list or a scripted source (``cdcr_ctl.sim.joystick``); :func:`open_evdev_joystick` makes one from
a real device with python-evdev, an optional dependency (``pip install 'cdcr-ctl[joystick]'``)
imported only there. :func:`open_tcp_joystick` makes one from a *network joystick*: the kernel's
``struct input_event`` records of a device streamed over TCP (:class:`InputEventParser`), the way
netevent-style tools and ``socat -u /dev/input/eventN TCP-LISTEN:PORT`` forward input devices;
:func:`open_joystick` picks the transport from the config's ``device``.

State is published atomically at each ``SYN_REPORT`` (the kernel's end of a consistent set).
After ``SYN_DROPPED`` (the kernel's buffer overflowed) events are ignored up to the next report,
and the device's full state is re-read when a ``resync`` callable is given.

Normalisation of a raw axis value ``v`` with range [min, max] (from the device's absinfo):
``u = clip((v - c) / h, -1, 1)`` with ``c = (min + max) / 2``, ``h = (max - min) / 2``; then the
deadband ``d``: ``0`` when ``|u| <= d``, else ``sign(u) (|u| - d) / (1 - d)``, so the output is
continuous and still reaches ±1.

This package re-exports every name of the former ``sensors/joystick.py``; its rooms: ``codes``
(event types and codes), ``reader`` (:class:`Joystick`, normalisation), ``evdev_device``
(:func:`open_evdev_joystick`), ``input_event`` (the 24-byte records, pure), ``network``
(:func:`open_tcp_joystick`) and ``opener`` (:func:`open_joystick`).
"""

from cdcr_ctl.sensors.joystick.codes import (
    ABS_CODES,
    ABS_NAMES,
    BUTTON_CODES,
    BUTTON_NAMES,
    EV_ABS,
    EV_KEY,
    EV_MAX,
    EV_SYN,
    SYN_DROPPED,
    SYN_REPORT,
    Event,
    axis_code,
    button_name,
)
from cdcr_ctl.sensors.joystick.evdev_device import EVDEV_POLL_S, open_evdev_joystick
from cdcr_ctl.sensors.joystick.input_event import (
    INPUT_EVENT,
    INPUT_EVENT_SIZE,
    InputEvent,
    InputEventError,
    InputEventParser,
    pack_input_event,
)
from cdcr_ctl.sensors.joystick.network import (
    TCP_KEEPCNT,
    TCP_KEEPIDLE_S,
    TCP_KEEPINTVL_S,
    TCP_POLL_S,
    open_tcp_joystick,
)
from cdcr_ctl.sensors.joystick.opener import open_joystick
from cdcr_ctl.sensors.joystick.reader import (
    DEFAULT_RANGE,
    AxisRange,
    Joystick,
    JoystickState,
    JoystickStats,
    config_axis_range,
)

__all__ = [
    "ABS_CODES",
    "ABS_NAMES",
    "BUTTON_CODES",
    "BUTTON_NAMES",
    "DEFAULT_RANGE",
    "EVDEV_POLL_S",
    "EV_ABS",
    "EV_KEY",
    "EV_MAX",
    "EV_SYN",
    "INPUT_EVENT",
    "INPUT_EVENT_SIZE",
    "SYN_DROPPED",
    "SYN_REPORT",
    "TCP_KEEPCNT",
    "TCP_KEEPIDLE_S",
    "TCP_KEEPINTVL_S",
    "TCP_POLL_S",
    "AxisRange",
    "Event",
    "InputEvent",
    "InputEventError",
    "InputEventParser",
    "Joystick",
    "JoystickState",
    "JoystickStats",
    "axis_code",
    "button_name",
    "config_axis_range",
    "open_evdev_joystick",
    "open_joystick",
    "open_tcp_joystick",
    "pack_input_event",
]
