"""CAN bus load of a cyclic PDO set: does it fit the SYNC period at the bit rate?

Worst-case length of a classical base-format (11-bit id) data frame with n data bytes: 44 + 8n
bits of frame (SOF, id, RTR, IDE, r0, DLC, data, CRC, delimiters, ACK, EOF) plus up to
floor((34 + 8n - 1) / 4) stuff bits over the 34 + 8n stuffed bits, plus the 3-bit intermission:
135 bits for 8 bytes, 55 bits for a 0-byte frame such as SYNC.

The cyclic set of one SYNC period is SYNC + each drive's cyclic RPDO + each drive's TPDO (see
:mod:`cdcr_ctl.drives.epos` for the layout per mode). Event-driven frames (controlword changes,
heartbeats at 50-100 ms, EMCY) are not in the budget; ``max_bus_load`` (70 % by default) leaves
room for them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cdcr_ctl.config.drives import DriveConfig
from cdcr_ctl.errors import ConfigError

#: Data bytes of the cyclic RPDO per mode (csp/pm: target int32; pp: target + controlword,
#: alternating set/clear of the new-set-point bit, at most one per cycle; ip: one PVT record).
RPDO_BYTES_BY_MODE = {"csp": 4, "pm": 4, "pp": 6, "ip": 8}
#: Data bytes of the cyclic TPDO: statusword (2) + actual position (4).
TPDO_BYTES = 6


def frame_bits(n_bytes: int) -> int:
    """Worst-case bits on the wire for a base-format data frame of ``n_bytes`` (0-8)."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"a classical CAN frame has 0-8 data bytes, not {n_bytes}")
    payload = 44 + 8 * n_bytes
    stuff = (34 + 8 * n_bytes - 1) // 4
    return payload + stuff + 3


@dataclass(frozen=True)
class BusLoad:
    """Bits per cycle, the time they take, and the fraction of the period (0..1+)."""

    bits_per_cycle: int
    time_per_cycle_s: float
    period_s: float
    bitrate: int

    @property
    def load(self) -> float:
        return self.time_per_cycle_s / self.period_s

    def __str__(self) -> str:
        return (
            f"{self.bits_per_cycle} bits per {self.period_s * 1e3:.3g} ms cycle at "
            f"{self.bitrate / 1e3:g} kbit/s: {100 * self.load:.1f} % bus load"
        )


def cycle_load(frame_sizes: Sequence[int], period_s: float, bitrate: int) -> BusLoad:
    """Load of the frames sent once per cycle (sizes in data bytes, SYNC included by caller)."""
    bits = sum(frame_bits(n) for n in frame_sizes)
    return BusLoad(bits, bits / bitrate, period_s, bitrate)


def pdo_cycle_frames(n_drives: int, rpdo_bytes: int = 4, tpdo_bytes: int = TPDO_BYTES) -> list[int]:
    """Frames of one cycle of ``n_drives`` alike drives: SYNC (0 bytes), one RPDO and one TPDO each.

    Three EPOS4 in CSP at 1 kHz and 1 Mbit/s: 55 + 3 * 95 + 3 * 115 = 685 bits, 68.5 %.
    """
    return [0] + [rpdo_bytes] * n_drives + [tpdo_bytes] * n_drives


def drive_cycle_frames(drives: Sequence[DriveConfig]) -> list[int]:
    """Frames of one cycle of these drives, each with the cyclic RPDO of its mode."""
    return [0] + [RPDO_BYTES_BY_MODE[d.mode] for d in drives] + [TPDO_BYTES for _ in drives]


def _refuse(load: BusLoad, max_load: float, file: str, period_s: float) -> BusLoad:
    if load.load > max_load:
        raise ConfigError(
            file,
            "can.sync_period_s",
            f"{load}; over the {100 * max_load:.0f} % limit (lengthen the SYNC period, raise the "
            "bit rate or split the drives over two buses)",
            period_s,
        )
    return load


def check_bus_load(
    n_drives: int, period_s: float, bitrate: int, max_load: float, file: str = ""
) -> BusLoad:
    """Raise :class:`ConfigError` when ``n_drives`` CSP drives do not fit ``max_load``."""
    return _refuse(
        cycle_load(pdo_cycle_frames(n_drives), period_s, bitrate), max_load, file, period_s
    )


def check_drives_bus_load(
    drives: Sequence[DriveConfig],
    period_s: float,
    bitrate: int,
    max_load: float,
    file: str = "",
) -> BusLoad:
    """Raise :class:`ConfigError` when these drives' cyclic PDO set does not fit ``max_load``."""
    return _refuse(
        cycle_load(drive_cycle_frames(drives), period_s, bitrate), max_load, file, period_s
    )
