"""The simulated world's physics: actuator positions in, robot pose and cable tensions out.

The truth is the same forward static model the controller could use
(:mod:`cdcr_ctl.model.cc_disk.forward`), with the simulator's own parameters (``truth_robot`` of the
simulator YAML) and effects: the exact chord geometry of the disk holes, friction with stick at
reversals, elastic cables, gravity, pulley losses, and transmission effects the controller's config
does not know (actuator scale error, backlash). Quasi-static: the robot's dynamics are far faster
than the cable motion.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from cdcr_ctl.config.build_model import loadcell_locations, robot_params
from cdcr_ctl.errors import ModelError
from cdcr_ctl.model import Effects, ForwardStepper
from cdcr_ctl.model.cc_disk.effects import with_cable_play
from cdcr_ctl.model.cc_disk.kinematics import tip_frame_fast
from cdcr_ctl.sim.friction_law import use_friction_law
from cdcr_ctl.sim.simconfig import LoadedSim

log = logging.getLogger(__name__)

#: Newton tolerance of the world's statics solve (largest scaled residual: moment / kEI and
#: length / routing radius, rad-equivalent). 1e-9 rather than the model's default 1e-11: on the
#: Qi rig's planar bend (1001 solves) the tip moves by at most 2.2e-8 mm and the tensions by
#: 2.6e-8 N against 1e-11, far below what the simulated sensors resolve (the tracker's float32
#: coordinates ~1e-5 mm at 200 mm, the load cells' last digit, 3 decimals by default), and each
#: solve needs about one Newton iteration fewer (5.2 -> 4.1 residual evaluations per solve).
TRUTH_TOL = 1e-9


@dataclass(frozen=True)
class TruthState:
    """One solved instant of the simulated world (base frame, mm, N, rad)."""

    q_act_mm: np.ndarray  # (K,) actuator displacement the drives produced
    psi: np.ndarray  # (S, 2)
    tip_mm: np.ndarray  # (3,)
    R_tip: np.ndarray  # (3, 3) tip frame in base frame
    tension_base_N: np.ndarray  # (K,)
    tension_actuator_N: np.ndarray  # (K,)


class SteppedTruth:
    """What every truth does with the drives' positions: counts -> cable mm through the TRUE
    transmission (``counts_per_mm``), one solve (``_solve``), the last solved state kept under a
    lock. A pose the world cannot take keeps the last one and is counted in ``failures``."""

    counts_per_mm: np.ndarray
    failures: int
    steps: int
    _lock: threading.Lock
    _state: Any

    def _solve(self, q_act_mm: np.ndarray) -> Any:
        raise NotImplementedError

    def step(self, counts: Sequence[int]) -> Any:
        """Advance the world to the drives' present positions (counts, cable order)."""
        q_act = np.asarray(counts, dtype=float) / self.counts_per_mm
        try:
            state = self._solve(q_act)
        except ModelError as exc:
            # A pose the world cannot hold (slack cables, out of reach): keep the last pose; the
            # controller's supervisor sees the tensions and the tip stop following.
            self.failures += 1
            log.warning("truth solve failed at q=%s: %s", np.round(q_act, 3), exc)
            return self.state
        with self._lock:
            self._state = state
            self.steps += 1
        return state

    @property
    def state(self) -> Any:
        with self._lock:
            assert self._state is not None
            return self._state


class TruthModel(SteppedTruth):
    """Thread-safe truth: :meth:`step` from drive counts, getters for the simulated sensors."""

    def __init__(self, loaded: LoadedSim) -> None:
        rig, eff = loaded.rig, loaded.sim.effects
        self.params = robot_params(loaded.truth)
        # Lost motion: each truth cable's own play (truth_robot.cables[].backlash_mm), or, when
        # the world's effects.backlash_mm is set, that width on every cable.
        if eff.backlash_mm > 0:
            self.params = replace(
                self.params,
                cables=tuple(replace(c, backlash_mm=eff.backlash_mm) for c in self.params.cables),
            )
        self.effects = Effects(
            disk_friction=eff.disk_friction,
            pulley_friction=eff.pulley_friction,
            elongation=eff.elongation,
            coupling=eff.coupling,
            gravity=eff.gravity,
            geometry=eff.geometry,
        )
        self.effects = with_cable_play(self.params, self.effects)
        self.stepper = ForwardStepper(self.params, self.effects, tol=TRUTH_TOL)
        self._speed_law = use_friction_law(
            self.stepper,
            eff.friction_law,
            exponent=eff.friction_exponent,
            static_ratio=eff.friction_static_ratio,
            stribeck_mm_s=eff.friction_stribeck_mm_s,
            viscous_s_per_mm=eff.friction_viscous_s_per_mm,
            memory_s=eff.friction_memory_s,
        )
        #: time between two steps (s), what a speed-dependent friction law's speeds are
        #: measured over: the physics rate of the simulated rig; a caller that steps the world
        #: at another rate (once per control cycle) sets it
        self.step_period_s = 1.0 / loaded.sim.physics_rate_hz
        by_cable = {d.cable: d for d in rig.drives}
        scale = eff.counts_per_mm_scale or [1.0] * len(rig.drives)
        # The truth's transmission: what the drives' counts really mean in cable millimetres.
        self.counts_per_mm = np.array(
            [
                by_cable[c.name].counts_per_mm * s
                for c, s in zip(rig.robot.cables, scale, strict=True)
            ]
        )
        self.node_ids = [by_cable[c.name].node_id for c in rig.robot.cables]
        self.lengths_mm = self.params.lengths_mm
        self._lengths = [float(v) for v in self.lengths_mm]
        self.cell_cable_index = []
        self.cell_location = []
        if rig.sensors.load_cells is not None:
            names = [c.name for c in rig.robot.cables]
            for cell in rig.sensors.load_cells.cells:
                self.cell_cable_index.append(names.index(cell.cable))
                self.cell_location.append(cell.location)
        self.locations = loadcell_locations(rig)
        self.failures = 0
        self.steps = 0
        self._lock = threading.Lock()
        self._state = self._solve(np.zeros(len(self.counts_per_mm)))

    def _solve(self, q_act: np.ndarray) -> TruthState:
        if self._speed_law is not None:
            # the cables slide at their drives' speed; the chain's coefficients change, so the
            # solver's cached evaluation of the last z is stale
            self._speed_law.observe(q_act.tolist(), self.step_period_s)
            self.stepper.model.forget_evaluation()
        r = self.stepper.step(q_act)
        R = r.R_tip if r.R_tip is not None else tip_frame_fast(r.x.tolist(), self._lengths)[0]
        return TruthState(
            q_act_mm=q_act.copy(),
            psi=r.psi.copy(),
            tip_mm=np.array(r.tip_mm, dtype=float),
            R_tip=np.array(R, dtype=float),
            tension_base_N=np.array(r.tension_base_N, dtype=float),
            tension_actuator_N=np.array(r.tension_actuator_N, dtype=float),
        )

    def cell_tensions(self) -> list[float]:
        """True tension at each load cell, in the config's cell order (N)."""
        s = self.state
        return [
            float((s.tension_base_N if loc == "robot_base" else s.tension_actuator_N)[k])
            for k, loc in zip(self.cell_cable_index, self.cell_location, strict=True)
        ]

    def tip_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(R_tip, p_tip_mm) in the robot base frame."""
        s = self.state
        return s.R_tip, s.tip_mm
