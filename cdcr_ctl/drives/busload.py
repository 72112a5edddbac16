"""CAN bus load of a cyclic PDO set: does it fit the SYNC period at the bit rate?

Worst-case length of a classical base-format (11-bit id) data frame with n data bytes:
44 + 8n bits of frame plus up to floor((34 + 8n - 1) / 4) stuff bits, plus the 3-bit
intermission: 135 bits for 8 bytes, 55 bits for a 0-byte frame such as SYNC.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cdcr_ctl.errors import ConfigError


def frame_bits(n_bytes: int) -> int:
    """Worst-case bits on the wire for a base-format data frame of ``n_bytes`` (0-8)."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"a classical CAN frame has 0-8 data bytes, not {n_bytes}")
    payload = 44 + 8 * n_bytes
    stuff = (34 + 8 * n_bytes - 1) // 4
    return payload + stuff + 3


@dataclass(frozen=True)
class BusLoad:
    """Bits per cycle, time they take, and the fraction of the period (0..1+)."""

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


def pdo_cycle_frames(n_drives: int, rpdo_bytes: int = 4, tpdo_bytes: int = 6) -> list[int]:
    """Frames of one CSP cycle: SYNC (0 bytes) plus one RPDO and one TPDO per drive.

    The cyclic RPDO carries only the target position (0x607A, 4 bytes); the controlword goes in
    an event-driven RPDO sent when it changes. The TPDO carries statusword + actual position
    (6 bytes). Three EPOS4 at 1 kHz and 1 Mbit/s: 55 + 3 * 95 + 3 * 115 = 685 bits, 68.5 %.
    """
    return [0] + [rpdo_bytes] * n_drives + [tpdo_bytes] * n_drives


def check_bus_load(
    n_drives: int, period_s: float, bitrate: int, max_load: float, file: str = ""
) -> BusLoad:
    """Raise :class:`ConfigError` when the cyclic PDO set does not fit ``max_load`` of the bus."""
    load = cycle_load(pdo_cycle_frames(n_drives), period_s, bitrate)
    if load.load > max_load:
        raise ConfigError(
            file,
            "can.sync_period_s",
            f"{load}; over the {100 * max_load:.0f} % limit (lengthen the SYNC period or "
            "raise the bit rate)",
            period_s,
        )
    return load
