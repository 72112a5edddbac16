"""Linux input event types and codes (linux/input-event-codes.h): the kernel ABI, as tables."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

#: Event types and codes of linux/input-event-codes.h (kernel ABI, fixed).
EV_SYN = 0x00
EV_KEY = 0x01
EV_ABS = 0x03
SYN_REPORT = 0
SYN_DROPPED = 3

#: Absolute-axis names -> codes (linux/input-event-codes.h).
ABS_CODES: Mapping[str, int] = MappingProxyType(
    {
        "ABS_X": 0x00,
        "ABS_Y": 0x01,
        "ABS_Z": 0x02,
        "ABS_RX": 0x03,
        "ABS_RY": 0x04,
        "ABS_RZ": 0x05,
        "ABS_THROTTLE": 0x06,
        "ABS_RUDDER": 0x07,
        "ABS_WHEEL": 0x08,
        "ABS_GAS": 0x09,
        "ABS_BRAKE": 0x0A,
        "ABS_HAT0X": 0x10,
        "ABS_HAT0Y": 0x11,
        "ABS_HAT1X": 0x12,
        "ABS_HAT1Y": 0x13,
    }
)
ABS_NAMES: Mapping[int, str] = MappingProxyType({v: k for k, v in ABS_CODES.items()})

#: Joystick and gamepad button codes -> names (linux/input-event-codes.h).
BUTTON_NAMES: Mapping[int, str] = MappingProxyType(
    {
        0x120: "BTN_TRIGGER",
        0x121: "BTN_THUMB",
        0x122: "BTN_THUMB2",
        0x123: "BTN_TOP",
        0x124: "BTN_TOP2",
        0x125: "BTN_PINKIE",
        0x126: "BTN_BASE",
        0x127: "BTN_BASE2",
        0x128: "BTN_BASE3",
        0x129: "BTN_BASE4",
        0x12A: "BTN_BASE5",
        0x12B: "BTN_BASE6",
        0x130: "BTN_SOUTH",
        0x131: "BTN_EAST",
        0x132: "BTN_C",
        0x133: "BTN_NORTH",
        0x134: "BTN_WEST",
        0x135: "BTN_Z",
        0x136: "BTN_TL",
        0x137: "BTN_TR",
        0x138: "BTN_TL2",
        0x139: "BTN_TR2",
        0x13A: "BTN_SELECT",
        0x13B: "BTN_START",
        0x13C: "BTN_MODE",
        0x13D: "BTN_THUMBL",
        0x13E: "BTN_THUMBR",
    }
)
BUTTON_CODES: Mapping[str, int] = MappingProxyType({v: k for k, v in BUTTON_NAMES.items()})


#: Highest event type of the kernel ABI (EV_MAX, linux/input-event-codes.h).
EV_MAX = 0x1F

Event = tuple[int, int, int]


def axis_code(name: str) -> int:
    """evdev code of an axis name (``"ABS_RY"``); ValueError naming the known ones otherwise."""
    try:
        return ABS_CODES[name]
    except KeyError:
        raise ValueError(f"unknown joystick axis {name!r} (know {', '.join(ABS_CODES)})") from None


def button_name(code: int) -> str:
    """Name of a button code (``BTN_SOUTH``), or ``KEY_<code>`` for other keys."""
    return BUTTON_NAMES.get(code, f"KEY_{code}")
