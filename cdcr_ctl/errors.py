"""One exception tree for the whole controller.

Every error a user can see derives from :class:`RigError`. Library errors (python-can, canopen,
pyserial, pymodbus) are wrapped with ``raise ... from`` at the layer that knows what was being done,
so the message names the file, key, node, port or frame at fault.
"""

from __future__ import annotations

from typing import Any


class RigError(Exception):
    """Base of every cdcr-ctl error."""


class ConfigError(RigError):
    """A config file is missing, unreadable or invalid.

    ``file`` is the YAML file, ``key`` the dotted key path inside it (``robot.cables[1].segment``),
    ``value`` the offending value when there is one.
    """

    def __init__(self, file: str, key: str, message: str, value: Any = None) -> None:
        self.file = str(file)
        self.key = key
        self.value = value
        self.detail = message
        where = f"{self.file}: {key}" if key else self.file
        shown = "" if value is None else f" (got {value!r})"
        super().__init__(f"{where}: {message}{shown}")


class ConfigErrors(ConfigError):
    """Several config errors found in one pass; ``errors`` lists them all."""

    def __init__(self, errors: list[ConfigError]) -> None:
        self.errors = errors
        first = errors[0]
        super().__init__(first.file, first.key, first.detail, first.value)
        self.args = ("\n".join(str(e) for e in errors),)

    def __str__(self) -> str:
        return self.args[0]


class CommError(RigError):
    """A transport failed: CAN bus, serial port, socket."""


class DriveFault(RigError):
    """A drive reported a fault or stopped answering.

    ``node`` is the CANopen node id, ``code`` the EMCY/error code (0 when none), ``text`` its
    meaning.
    """

    def __init__(self, node: int, code: int, text: str) -> None:
        self.node = node
        self.code = code
        self.text = text
        # EMCY codes are 16 bit, SDO abort codes 32 bit: always all their digits (0x06090011).
        shown = f"0x{code:04X}" if code <= 0xFFFF else f"0x{code:08X}"
        super().__init__(f"node {node}: {shown} {text}")


class SensorError(RigError):
    """A sensor is disconnected, silent or returning garbage; ``port`` names where."""

    def __init__(self, port: str, message: str) -> None:
        self.port = port
        super().__init__(f"{port}: {message}")


class RigTimeoutError(RigError, TimeoutError):
    """Something did not happen within its named timeout."""


class ModelError(RigError):
    """The physics model cannot produce an answer (unreachable pose, solver failure)."""


class SafetyTrip(RigError):
    """The safety supervisor stopped the motors; ``cause`` names the limit that tripped."""

    def __init__(self, cause: str, reaction: str) -> None:
        self.cause = cause
        self.reaction = reaction
        super().__init__(f"{cause} -> {reaction}")
