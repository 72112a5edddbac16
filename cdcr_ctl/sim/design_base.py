"""What the truths of the universal-joint and vertebra designs share with :class:`TruthModel`:
their state, the world's rig config and the thread-safe stepping base.

The simulator's rig (:class:`cdcr_ctl.sim.rig.SimRig`) asks a truth for :meth:`step` (drive counts
in, the world advanced), :meth:`cell_tensions` (load cells), :meth:`tip_pose` (tracker) and, for
the vertebra arm, the attitude sensors' orientations. :func:`cdcr_ctl.sim.design_truth.make_truth`
picks the truth of the rig's ``design``.

The truth's parameters: the rig's ``robot:`` section with the simulator's ``truth_robot`` merged
over it (:func:`cdcr_ctl.sim.simconfig.load_sim_config`), and the rig's design section
(``ujoint:``/``vertebra:``) with the simulator's ``truth_design`` merged over it, so the world's
dead zone, deformation, stiffness or masses can differ from what the controller believes.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from cdcr_ctl.config.loader import merge_tree, validate_mapping
from cdcr_ctl.config.registry import design_of
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import ConfigError
from cdcr_ctl.sim.simconfig import LoadedSim
from cdcr_ctl.sim.truth import SteppedTruth

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DesignTruthState:
    """One solved instant (base frame, mm, N, rad): the drives' cable displacements, the joint
    poses in the loop's (bend, direction) rows, the tip, and the cable tensions (NaN unknown)."""

    q_act_mm: np.ndarray
    psi: np.ndarray
    tip_mm: np.ndarray
    R_tip: np.ndarray
    tension_N: np.ndarray


def truth_rig_config(loaded: LoadedSim) -> RigConfig:
    """The rig config of the simulated WORLD: truth robot, and the design section with the
    simulator's ``truth_design`` merged over it (validated; errors name the simulator file)."""
    rig = loaded.rig
    design = design_of(rig.design)
    key = design.section
    section = None if key is None else getattr(rig, key, None)
    over: dict[str, Any] = dict(getattr(loaded.sim, "truth_design", {}) or {})
    if section is None:
        if over:
            raise ConfigError(
                str(loaded.path), "truth_design", f"design {rig.design} has no design section", over
            )
        return rig.model_copy(update={"robot": loaded.truth})
    data = rig.model_dump()
    data["robot"] = loaded.truth.model_dump()
    data[key] = merge_tree(section.model_dump(), over, (), {}, str(loaded.path))
    try:
        return validate_mapping(data, RigConfig, str(loaded.path))
    except ConfigError as exc:
        raise ConfigError(
            str(loaded.path), f"truth_design.{exc.key}", exc.detail, exc.value
        ) from exc


class DesignTruth(SteppedTruth):
    """Thread-safe base: counts -> cable mm through the TRUE transmission, failure handling,
    locking and the sensor getters. Subclasses implement :meth:`_solve` (q_act_mm -> state)."""

    def __init__(self, loaded: LoadedSim) -> None:
        rig, eff = loaded.rig, loaded.sim.effects
        self.loaded = loaded
        self.world = truth_rig_config(loaded)
        by_cable = {d.cable: d for d in rig.drives}
        scale = eff.counts_per_mm_scale or [1.0] * len(rig.drives)
        #: What the drives' counts really mean in cable millimetres (actuator scale error).
        self.counts_per_mm = np.array(
            [
                by_cable[c.name].counts_per_mm * s
                for c, s in zip(rig.robot.cables, scale, strict=True)
            ]
        )
        self.node_ids = [by_cable[c.name].node_id for c in rig.robot.cables]
        names = [c.name for c in rig.robot.cables]
        self.cell_cable_index = (
            [names.index(cell.cable) for cell in rig.sensors.load_cells.cells]
            if rig.sensors.load_cells is not None
            else []
        )
        self.failures = 0
        self.steps = 0
        self._lock = threading.Lock()
        self._state: DesignTruthState | None = None

    def _start(self) -> None:
        """Solve the homed world (all cables at 0); subclasses call it at the end of __init__."""
        self._state = self._solve(np.zeros(len(self.counts_per_mm)))

    def _solve(self, q_act_mm: np.ndarray) -> DesignTruthState:
        raise NotImplementedError

    def cell_tensions(self) -> list[float]:
        """True tension of each load cell's cable, in the config's cell order (N)."""
        t = self.state.tension_N
        return [float(t[k]) for k in self.cell_cable_index]

    def tip_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(R_tip, p_tip_mm) in the robot base frame."""
        s = self.state
        return s.R_tip, s.tip_mm
