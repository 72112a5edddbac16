"""What the loop needs from drives and sensors, as small protocols.

The loop never sees ``can.Message`` or serial bytes: it sees counts, newtons and millimetres with
ages. Adapters in :mod:`cdcr_ctl.control.io` wrap the protocol layers (``cdcr_ctl.drives``,
``cdcr_ctl.sensors``) into these shapes; tests can pass plain fakes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


@dataclass(frozen=True)
class DriveState:
    """Latest feedback of one drive: position (counts), CiA 402 state name, fault text or ''."""

    position_counts: int
    state: str
    fault: str
    age_s: float


class DrivePort(Protocol):
    """All drives of the rig, in cable order."""

    def send_cycle(self, targets_counts: Sequence[int]) -> None:
        """Send one cycle's position targets (counts) and the SYNC that applies them."""

    def feedback(self) -> list[DriveState]:
        """Latest feedback per drive; never blocks. (A port may also offer ``positions()``:
        the ``position_counts`` of each, which the loop then reads every cycle instead.)"""

    def first_fault(self) -> tuple[str, str] | None:
        """(cause, text) of the first drive/bus fault seen since the last reset, or None."""

    def enable(self) -> None: ...

    def disable(self) -> None: ...

    def quick_stop(self) -> None:
        """CiA 402 quick stop of every drive; must not raise (best effort on a broken bus)."""

    def home(self) -> list[int]:
        """Home every drive (blocking, not on the loop's path); return the home counts."""

    def reset_faults(self) -> list[str] | None:
        """Reset drive faults; lines naming drives reconfigured after a reboot (or None)."""

    def close(self) -> None: ...


class TensionPort(Protocol):
    def latest(self) -> tuple[np.ndarray, np.ndarray]:
        """(force_N per cable, age_s per cable); NaN force where a cell has no sample. (A port
        may also offer ``latest_lists()``: the same values as two lists of floats, which the
        loop then reads every cycle instead.)"""

    def close(self) -> None: ...


class TipPort(Protocol):
    def latest(self) -> tuple[np.ndarray, float]:
        """(tip xyz in the robot base frame, mm; age_s). NaNs and inf age when none."""

    def close(self) -> None: ...


class AttitudePort(Protocol):
    """Attitude sensors, one per joint end (vertebra design), in joint order."""

    def latest(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(roll_rad (N,), pitch_rad (N,), age_s (N,)) of each sensor's newest reading (the
        sensor's Z-Y-X Euler angles, world z up); NaN angles and inf age where none. Never
        blocks. Yaw is not part of it (the magnetometer heading is not trusted)."""

    def close(self) -> None: ...


class NoTension:
    """A rig without load cells."""

    def __init__(self, n: int) -> None:
        self._f = np.full(n, np.nan)
        self._age = np.full(n, np.inf)

    def latest(self) -> tuple[np.ndarray, np.ndarray]:
        return self._f, self._age

    def close(self) -> None:
        pass


class NoTip:
    """A rig without a tracker."""

    def latest(self) -> tuple[np.ndarray, float]:
        return np.full(3, np.nan), float("inf")

    def close(self) -> None:
        pass


class SetpointSource(Protocol):
    """A timed setpoint: segment (theta, phi) per segment, shape (S, 2), rad."""

    @property
    def duration_s(self) -> float: ...

    def sample(self, t_s: float) -> np.ndarray: ...


@dataclass
class RigIO:
    """The opened hardware (or simulated hardware) of one rig, as the daemon's loop uses it."""

    drives: DrivePort
    tensions: TensionPort
    tip: TipPort
    close: Callable[[], None]
    #: Per-joint attitude sensors (:class:`AttitudePort`) or None.
    attitude: Any = None


def attach_attitude(model: Any, io: RigIO) -> None:
    """Hand ``model`` the rig's attitude sensors, if it takes them (``attach_attitude``, see
    above) and the rig has them."""
    attach = getattr(model, "attach_attitude", None)
    if attach is not None and io.attitude is not None:
        attach(io.attitude)
