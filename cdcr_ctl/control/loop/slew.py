"""Rate bound of the ``measured`` compensation mode's output.

In mode ``measured`` the compensation term delta = q_command - q_nominal (mm, per cable) follows
the load-cell tensions (Qi et al. 2023 eq. 37 with measured T instead of modelled ones). Those
change as fast as the world does: a reversal flips the friction in a few cycles, and a return
from a 90 deg bend changed delta on cable 1 by 0.28 mm in one 4 ms cycle on the hard simulated
world (68.8 mm/s against the 40 mm/s limit). Like the dead zone's pre-travel
(:func:`cdcr_ctl.model.shared.deadzone.dead_zone_inverse`), the term therefore moves towards its
target by at most what the velocity limit leaves after the trajectory's own step: per cable,
room = max(COMMAND_STEP_FRACTION v dt - |q_nominal - q_nominal_prev|, 0) (mm per cycle).

Units: mm, mm/s, s.
"""

from __future__ import annotations

import numpy as np


class MeasuredSlew:
    """The bounded compensation term of mode ``measured`` (owned by the loop thread)."""

    def __init__(self, step_budget_mm: float) -> None:
        #: Largest whole command step per cycle the bound aims at (mm): the loop's
        #: COMMAND_STEP_FRACTION of the velocity limit times the period.
        self.step_budget_mm = step_budget_mm
        self._delta: np.ndarray | None = None

    def reset(self) -> None:
        """Start again at the next target (a mode switch, home, an adopted pose: the loop's
        offset takes that step and ramps it out)."""
        self._delta = None

    def bound(
        self, q_nominal_mm: np.ndarray, q_nominal_prev_mm: np.ndarray, q_command_mm: np.ndarray
    ) -> np.ndarray:
        """The command (mm) with its delta moved towards ``q_command_mm - q_nominal_mm`` by at
        most the room the nominal step ``q_nominal_mm - q_nominal_prev_mm`` leaves."""
        target = np.asarray(q_command_mm, dtype=float) - q_nominal_mm
        if self._delta is None:
            self._delta = target
        else:
            room = np.maximum(self.step_budget_mm - np.abs(q_nominal_mm - q_nominal_prev_mm), 0.0)
            self._delta = self._delta + np.clip(target - self._delta, -room, room)
        return q_nominal_mm + self._delta


__all__ = ["MeasuredSlew"]
