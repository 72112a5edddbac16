"""CiA 402 (drives and motion control) state machine: statusword decoding, controlwords, modes.

Pure functions and constants, no I/O. The state of a drive is read from its statusword
(0x6041) with the masks of CiA 402 (statusword bits 0-3, 5, 6); the next controlword (0x6040) on
the way to a target state follows the state diagram: e.g. SWITCH ON DISABLED -> 0x06 -> READY TO
SWITCH ON -> 0x07 -> SWITCHED ON -> 0x0F -> OPERATION ENABLED.
"""

from __future__ import annotations

import enum
import functools


class State(enum.Enum):
    """CiA 402 power state machine states (values are the names canopen's BaseNode402 uses)."""

    NOT_READY_TO_SWITCH_ON = "NOT READY TO SWITCH ON"
    SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
    READY_TO_SWITCH_ON = "READY TO SWITCH ON"
    SWITCHED_ON = "SWITCHED ON"
    OPERATION_ENABLED = "OPERATION ENABLED"
    QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
    FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
    FAULT = "FAULT"
    UNKNOWN = "UNKNOWN"


# (mask, value) per state: statusword bits 0-3, 5, 6.
_SW_PATTERNS: tuple[tuple[int, int, State], ...] = (
    (0x4F, 0x00, State.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, State.SWITCH_ON_DISABLED),
    (0x6F, 0x21, State.READY_TO_SWITCH_ON),
    (0x6F, 0x23, State.SWITCHED_ON),
    (0x6F, 0x27, State.OPERATION_ENABLED),
    (0x6F, 0x07, State.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, State.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, State.FAULT),
)

#: Statusword bits 0-6 a drive reports in each state (the inverse of :func:`state_of`).
STATE_BITS: dict[State, int] = {
    State.NOT_READY_TO_SWITCH_ON: 0x00,
    State.SWITCH_ON_DISABLED: 0x40,
    State.READY_TO_SWITCH_ON: 0x21,
    State.SWITCHED_ON: 0x23,
    State.OPERATION_ENABLED: 0x27,
    State.QUICK_STOP_ACTIVE: 0x07,
    State.FAULT_REACTION_ACTIVE: 0x0F,
    State.FAULT: 0x08,
}

# Controlword commands (bits 0-3 and 7).
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_DISABLE_OPERATION = 0x0007
CW_FAULT_RESET = 0x0080
#: Bit 8: halt (decelerate with the profile deceleration and hold).
CW_HALT_BIT = 0x0100
#: Homing: "homing operation start" is bit 4 in homing mode.
CW_HOMING_START_BIT = 0x0010
#: Profile position: bit 4 new set-point, bit 5 change set immediately, bit 6 relative.
CW_NEW_SETPOINT_BIT = 0x0010
CW_CHANGE_IMMEDIATELY_BIT = 0x0020
CW_RELATIVE_BIT = 0x0040
#: Interpolated position: bit 4 enables the interpolation (starts consuming the buffer).
CW_IP_ENABLE_BIT = 0x0010

# Statusword bits
SW_VOLTAGE_ENABLED = 1 << 4
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_SETPOINT_ACK = 1 << 12  # profile position: set-point acknowledge
SW_HOMING_ATTAINED = 1 << 12  # homing: homing attained
SW_IP_ACTIVE = 1 << 12  # interpolated position: interpolation active
SW_FOLLOWING_COMMAND = 1 << 12  # cyclic synchronous position: drive follows the command value
SW_HOMING_ERROR = 1 << 13  # homing: homing error
SW_FOLLOWING_ERROR = 1 << 13  # position modes: following error
SW_POSITION_REFERENCED = 1 << 15  # EPOS4: position referenced to the home position


class Mode(enum.IntEnum):
    """Modes of operation (0x6060 / 0x6061); negative values are maxon-specific."""

    POSITION_MODE = -1  # EPOS2 "position mode": set-point 0x2062, no profile
    PROFILE_POSITION = 1
    PROFILE_VELOCITY = 3
    HOMING = 6
    INTERPOLATED_POSITION = 7
    CYCLIC_SYNC_POSITION = 8


MODE_BY_NAME = {
    "pp": Mode.PROFILE_POSITION,
    "ip": Mode.INTERPOLATED_POSITION,
    "csp": Mode.CYCLIC_SYNC_POSITION,
    "pm": Mode.POSITION_MODE,
}


@functools.cache  # a handful of distinct statuswords; called for every TPDO
def state_of(statusword: int) -> State:
    """The CiA 402 state a statusword reports."""
    for mask, value, state in _SW_PATTERNS:
        if statusword & mask == value:
            return state
    return State.UNKNOWN


def next_controlword(current: State, target: State) -> int | None:
    """The controlword that takes a drive one step from ``current`` towards ``target``.

    Targets are the stable states SWITCH_ON_DISABLED, READY_TO_SWITCH_ON, SWITCHED_ON and
    OPERATION_ENABLED. None when already there or when no command leads on (from FAULT the caller
    resets first with :data:`CW_FAULT_RESET`, which this returns; NOT READY TO SWITCH ON and FAULT
    REACTION ACTIVE are left by the drive itself).
    """
    if current is target:
        return None
    if current is State.FAULT:
        return CW_FAULT_RESET if target is not State.FAULT else None
    if current in (State.NOT_READY_TO_SWITCH_ON, State.FAULT_REACTION_ACTIVE, State.UNKNOWN):
        return None
    if target is State.SWITCH_ON_DISABLED:
        return CW_DISABLE_VOLTAGE
    order = [State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.OPERATION_ENABLED]
    if target not in order:
        return None
    if current is State.SWITCH_ON_DISABLED:
        return CW_SHUTDOWN
    if current is State.QUICK_STOP_ACTIVE:
        return CW_DISABLE_VOLTAGE  # transition 12; the walk continues from SWITCH ON DISABLED
    here, there = order.index(current), order.index(target)
    if there > here:
        return (CW_SWITCH_ON, CW_ENABLE_OPERATION)[here]
    return (CW_SHUTDOWN, CW_DISABLE_OPERATION)[there]
