"""Tracker, attitude-sensor and joystick sections of the rig config."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from cdcr_ctl.config.base import Section, Timeout
from cdcr_ctl.config.loadcells import SerialPortConfig
from cdcr_ctl.config.robot import PositiveFloat

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Port = Annotated[int, Field(ge=1, le=65535)]

#: Tracker units per mm when ``units_to_mm`` is not given: Motive streams metres over NatNet;
#: the plain line stream (see :mod:`cdcr_ctl.sensors.tracker`) is defined in mm.
DEFAULT_UNITS_TO_MM = {"natnet": 1000.0, "udp_stream": 1.0, "tcp_stream": 1.0}


class RigidTransformConfig(Section):
    """A rigid transform: rotation vector (axis * angle, rad), then translation (mm).

    As a map of points: ``x_to = R(rotvec_rad) @ x_from + translation_mm``.
    """

    #: Rotation as a rotation vector (axis times angle).
    rotvec_rad: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])
    #: Translation after the rotation.
    translation_mm: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])


class TrackerConfig(Section):
    """Tip tracker: OptiTrack NatNet rigid body, or a plain UDP/TCP line stream (laser tracker).

    ``base_from_tracker`` maps tracker-frame points (mm) into the robot base frame (mm);
    ``marker_to_tip`` is the tip in the rigid body's own frame (its translation is the tip point,
    mm; its rotation the tip frame's orientation in the body frame). ``units_to_mm``: mm per
    tracker unit (None: 1000 for NatNet, whose Motive streams metres; 1 for the line streams).

    ``kind: natnet``: ``host`` is the Motive PC, ``command_port`` its command port (NAT_CONNECT,
    keep-alives); in unicast mode (``multicast_group`` None) frames come back to the client's own
    socket; with a multicast group the client also joins it on ``port`` (the data port).
    ``kind: udp_stream``: the controller listens on ``host``:``port`` for datagrams of lines.
    ``kind: tcp_stream``: the controller connects to the sender at ``host``:``port``.
    ``local_address``: local interface to bind (None: 127.0.0.1 when ``host`` is a loopback
    address, else all interfaces). ``stale_after_s``: a tip older than this is flagged stale (s);
    ``lost_after_s``: silence after which the tracker counts as lost and the client re-connects
    (s); ``connect_timeout_s``: wait for the server's reply at start-up (s).
    """

    #: Which tracker: ``natnet`` (OptiTrack Motive) or a plain ``udp_stream`` / ``tcp_stream`` of
    #: lines (laser tracker).
    kind: Literal["natnet", "udp_stream", "tcp_stream"] = "natnet"
    host: str = "127.0.0.1"
    port: Port = 1511
    command_port: Port = 1510
    multicast_group: str | None = None
    local_address: str | None = None
    #: NatNet rigid-body id of the tip marker set (Motive's Streaming ID).
    rigid_body_id: int = 1
    units_to_mm: PositiveFloat | None = None
    base_from_tracker: RigidTransformConfig = Field(default_factory=RigidTransformConfig)
    marker_to_tip: RigidTransformConfig = Field(default_factory=RigidTransformConfig)
    stale_after_s: Timeout = 0.1
    lost_after_s: Timeout = 1.0
    connect_timeout_s: Timeout = 2.0

    @property
    def mm_per_unit(self) -> float:
        """mm per tracker unit: ``units_to_mm`` or the default of ``kind``."""
        return self.units_to_mm if self.units_to_mm is not None else DEFAULT_UNITS_TO_MM[self.kind]


class AttitudeSensorsConfig(Section):
    """WitMotion JY901/WT901 attitude sensors, one per joint (vertebra design), each on a port.

    ``sensors`` in joint order, base first. ``stale_after_s``: an orientation older than this is
    flagged stale (s).
    """

    sensors: Annotated[list[SerialPortConfig], Field(min_length=1)]
    stale_after_s: Timeout = 0.1


#: URL scheme of the network joystick (:func:`cdcr_ctl.sensors.joystick.open_tcp_joystick`).
TCP_SCHEME = "tcp://"


def parse_tcp_url(url: str) -> tuple[str, int]:
    """``tcp://HOST:PORT`` -> (host, port); ValueError saying what is wrong otherwise.

    HOST is a name or an IPv4 address (an IPv6 address in brackets, ``tcp://[::1]:5000``);
    PORT 1..65535; no user, path, query or fragment.
    """
    if not url.startswith(TCP_SCHEME):
        raise ValueError(f"a network joystick is tcp://HOST:PORT, got {url!r}")
    rest = url[len(TCP_SCHEME) :]
    if any(c in rest for c in "/?#@"):
        raise ValueError(f"tcp://HOST:PORT has no user, path, query or fragment: {url!r}")
    host, sep, port = rest.rpartition(":")
    if not sep or not host:
        raise ValueError(f"tcp://HOST:PORT needs a host and a port: {url!r}")
    if host.startswith("["):
        if not host.endswith("]") or len(host) < 3:
            raise ValueError(f"unbalanced brackets around the IPv6 address: {url!r}")
        host = host[1:-1]
    elif ":" in host or "[" in host or "]" in host:
        raise ValueError(f"put an IPv6 address in brackets: {url!r}")
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"port must be 1..65535: {url!r}")
    return host, int(port)


class AxisRangeConfig(Section):
    """Raw range of the steering axes (device units): what evdev's absinfo says for a local
    device. A network joystick sends only events (no absinfo), so its range comes from here."""

    #: Lowest raw axis value (full deflection one way).
    min: int = -32768
    #: Highest raw axis value (full deflection the other way).
    max: int = 32767

    @model_validator(mode="after")
    def _ordered(self) -> AxisRangeConfig:
        if self.max <= self.min:
            raise ValueError(f"max ({self.max}) must be above min ({self.min})")
        return self


class JoystickConfig(Section):
    """Joystick: a local evdev device or a network joystick, and the two steering axes.

    ``device``: an evdev node (an absolute path: ``/dev/input/event5``,
    ``/dev/input/by-id/...-event-joystick``); ``tcp://HOST:PORT``: a network joystick, i.e. the
    Linux ``struct input_event`` records of a device streamed over TCP by a sender that listens
    there (:func:`cdcr_ctl.sensors.joystick.open_tcp_joystick`); None: the first local input
    device that has both axes. ``axis_x``/``axis_y``: evdev axis names (``ABS_X``, ``ABS_RY``,
    ...). ``axis_range``: raw range of both steering axes; required in effect for a network
    joystick (default: signed 16 bit), and when given it overrides a local device's absinfo.
    ``deadband``: fraction of the half-range around the centre that reads as 0.
    ``invert_x``/``invert_y``: flip an axis (many sticks report "forward" as negative).
    ``advance_button``: the "forward" button of end-following (paper Fig. 12), an evdev button
    name. ``connect_timeout_s``: how long opening a network joystick waits for the sender (s).
    """

    device: str | None = None
    axis_x: str = "ABS_X"
    axis_y: str = "ABS_Y"
    axis_range: AxisRangeConfig | None = None
    deadband: Annotated[float, Field(ge=0, lt=1)] = 0.05
    invert_x: bool = False
    invert_y: bool = False
    advance_button: Annotated[str, Field(pattern=r"^(BTN|KEY)_[A-Z0-9_]+$")] = "BTN_SOUTH"
    connect_timeout_s: Timeout = 2.0

    @field_validator("device")
    @classmethod
    def _device(cls, value: str | None) -> str | None:
        if value is None:
            return value
        if "://" in value:
            parse_tcp_url(value)
        elif not value.startswith("/"):
            raise ValueError(f"an evdev device is an absolute path or tcp://HOST:PORT: {value!r}")
        return value

    @property
    def tcp_address(self) -> tuple[str, int] | None:
        """(host, port) of a network joystick, None for an evdev device."""
        if self.device is None or not self.device.startswith(TCP_SCHEME):
            return None
        return parse_tcp_url(self.device)
