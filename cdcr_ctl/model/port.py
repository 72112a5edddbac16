"""The protocol every design's model implements for the control loop (``RobotModelPort``).

It lives in the model layer so that both sides see it without an upward import: the models
(``cdcr_ctl.model``) and the config's model builder (``cdcr_ctl.config.build_model``) below the
loop, the loop (``cdcr_ctl.control``) and the daemon above it.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class RobotModelPort(Protocol):
    """The design's model as the loop uses it; one implementation per design in ``cdcr_ctl.model``.

    ``psi`` is (S, 2): bend theta and direction phi per segment (rad). Cable displacements are mm
    pulled in, in cable order. ``state`` carries friction/hysteresis memory between cycles.
    """

    n_segments: int
    n_cables: int

    def new_state(self) -> object: ...

    def q_nominal(self, psi: np.ndarray) -> np.ndarray:
        """Ideal inverse kinematics (no compensation), mm."""

    def q_command(
        self,
        psi: np.ndarray,
        q_nominal: np.ndarray,
        state: object,
        mode: str,
        measured_N: np.ndarray | None,
    ) -> np.ndarray:
        """Displacement to send: ``q_nominal`` plus the compensation of ``mode`` (mm)."""

    def tip(self, psi: np.ndarray) -> np.ndarray:
        """Tip position in the robot base frame (mm) for ``psi``."""

    # Optional (a design with joint attitude sensors, e.g. ``model.vertebra.VertebraModel``):
    # ``attach_attitude(port: AttitudePort | None) -> None`` hands the model the sensors its
    # compensation mode ``measured`` closes the loop on. Whoever opens the sensors calls it.
