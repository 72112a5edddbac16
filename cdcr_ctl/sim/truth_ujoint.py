"""The simulated world of a universal-joint arm (Yang et al. 2022): drives in, arm pose out.

Per physics step (:func:`cdcr_ctl.model.ujoint.truth_angles` with the WORLD's parameters, see
:mod:`cdcr_ctl.sim.design_truth`): the cable outputs follow the drive inputs through the dead zone
(stick at reversal, width linear in pretension, section 4.1); the segment angles follow from the
outputs by the pseudo-inverse iteration with the cross-segment coupling (eq. 8-12); the distal
segments' drive torque deforms the proximal ones (eq. 14/16-17); and the cables' elasticity and
pretension hold the links against gravity (small-deflection statics: the sag of the long arm when
``robot.gravity_mm_s2`` is set, e.g. a cantilever off the air-bearing table). Quasi-static.

Truth effects (``effects:`` of the simulator YAML) that apply: ``disk_friction`` (the dead zone:
friction in the holes), ``coupling`` (the proximal deformation), ``elongation`` and ``gravity``
(the statics; gravity False zeroes it), ``counts_per_mm_scale`` (transmission error).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cdcr_ctl.config.designs import ujoint_arm
from cdcr_ctl.model import ujoint as uj
from cdcr_ctl.sim.design_base import DesignTruth, DesignTruthState
from cdcr_ctl.sim.simconfig import LoadedSim


class UJointTruth(DesignTruth):
    """Thread-safe universal-joint truth; ``state.psi`` rows are (sub-joint tilt, direction)."""

    def __init__(self, loaded: LoadedSim) -> None:
        super().__init__(loaded)
        eff = loaded.sim.effects
        arm = ujoint_arm(self.world, str(loaded.path))
        if not eff.gravity:
            arm = replace(arm, gravity_mm_s2=(0.0, 0.0, 0.0))
        self.arm = arm
        self.effects = uj.UJointEffects(
            dead_zone=eff.disk_friction,
            deformation=eff.coupling,
            statics=eff.elongation,
            # the world's friction torque reverses while the distal cables cross their dead
            # zone (UJointEffects docstring), not at the first backward twitch of the angle
            friction_driven_deformation=True,
        )
        # the statics runs apart from the kinematics below, so that it also gives the tensions
        self._kin_effects = replace(self.effects, statics=False)
        self._memory: uj.UJointTruthState | None = None
        #: Sub-joint angles (theta_{2n-1}, theta_{2n}) of the last solved step (rad).
        self.theta = np.zeros((arm.n_segments, 2))
        self._start()

    def _solve(self, q_act_mm: np.ndarray) -> DesignTruthState:
        theta, memory = uj.truth_angles(self.arm, q_act_mm, self._memory, self._kin_effects)
        tension = np.full(self.arm.n_cables, np.nan)
        if self.effects.statics:
            theta, tension = uj.statics_angles(self.arm, theta)
        else:
            tension = self.arm.pretension_N.copy()
        T = uj.tip_transform(self.arm, theta)
        self._memory = memory
        self.theta = theta
        return DesignTruthState(
            q_act_mm=q_act_mm.copy(),
            psi=uj.psi_from_joint_angles(theta),
            tip_mm=T[:3, 3].copy(),
            R_tip=T[:3, :3].copy(),
            tension_N=np.asarray(tension, dtype=float),
        )
