"""The simulated world of the vertebra arm (fuel-tank paper): drives in, joint poses and the
attitude sensors' orientations out.

Per physics step, with the WORLD's parameters (:mod:`cdcr_ctl.sim.design_truth`): the joints'
kinematic poses from the cable displacements (inverse of eq. 5, proximal first), then the
small-deflection statics of :func:`cdcr_ctl.model.vertebra.statics_x`: the NiTi rod's stiffness,
the cables' elasticity and pretension (slack cables drop out) and gravity on the disks and the tip
mass, which makes the long arm sag (the paper's Fig. 12(f) error). The sensor on joint i's end
reads the world orientation of that end frame (times its mount rotation).

World frame of the sensors: z up (against gravity), so an upright base (gravity along -z of the
base frame) is the identity; otherwise the base is turned by the smallest rotation that takes
-gravity to z. The sensors' heading (yaw) is arbitrary and is not used by the decode.

Truth effects that apply: ``elongation`` (the statics; False: pure kinematics), ``gravity``,
``counts_per_mm_scale``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cdcr_ctl.config.designs import sensor_mounts, vertebra_arm
from cdcr_ctl.model import vertebra as vt
from cdcr_ctl.sim.design_base import DesignTruth, DesignTruthState
from cdcr_ctl.sim.simconfig import LoadedSim


def world_from_base(gravity_mm_s2: np.ndarray) -> np.ndarray:
    """Rotation base -> world (z up) for gravity given in the base frame; identity when there
    is none or it is along -z."""
    g = np.asarray(gravity_mm_s2, dtype=float)
    n = float(np.linalg.norm(g))
    if n == 0.0:
        return np.eye(3)
    up = -g / n
    axis = np.cross(up, [0.0, 0.0, 1.0])
    s, c = float(np.linalg.norm(axis)), float(up[2])
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return vt.rotvec_matrix(axis / s * np.arctan2(s, c))


class VertebraTruth(DesignTruth):
    """Thread-safe vertebra truth with :meth:`sensor_orientation` for the attitude sensors."""

    def __init__(self, loaded: LoadedSim) -> None:
        super().__init__(loaded)
        eff = loaded.sim.effects
        arm = vertebra_arm(self.world, str(loaded.path))
        self.R_world_base = world_from_base(np.asarray(arm.gravity_mm_s2))
        if not eff.gravity:
            arm = replace(arm, gravity_mm_s2=(0.0, 0.0, 0.0))
        self.arm = arm
        self.statics = eff.elongation
        mounts = sensor_mounts(self.world)
        self.mounts = mounts or [np.eye(3)] * arm.n_joints
        self._x = np.zeros((arm.n_joints, 2))
        #: The last kinematic pose and sag (warm starts of the next step's solvers).
        self._x_kin = np.zeros((arm.n_joints, 2))
        self._dx: np.ndarray | None = None
        self._phi = np.zeros(arm.n_joints)
        #: The joint-end orientations of the state they were computed from (see
        #: :meth:`sensor_orientation`).
        self._ends: tuple[object, list[np.ndarray]] = (None, [])
        self._start()

    def _end_rotations(self, psi: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Orientation of each joint's end frame in the base frame, and the tip transform
        (4x4), for the joint angles ``psi`` (N, 2; rad): the chain of eq. 1's joint transforms."""
        T = np.eye(4)
        ends = []
        for i, j in enumerate(self.arm.joints):
            T = T @ vt.joint_transform(psi[i, 0], psi[i, 1], j)
            ends.append(T[:3, :3].copy())
        return ends, T

    def _solve(self, q_act_mm: np.ndarray) -> DesignTruthState:
        x_kin = vt.joints_from_displacements(self.arm, q_act_mm, self._x_kin)
        x, tension = x_kin, self.arm.pretensions.copy()
        if self.statics:
            x, tension = vt.statics_x(self.arm, x_kin, self._dx)
            self._dx = x - x_kin
        self._x_kin = x_kin
        psi = vt.psi_from_xs(x, self._phi)
        _ends, T = self._end_rotations(psi)
        self._x, self._phi = x, psi[:, 1].copy()
        return DesignTruthState(
            q_act_mm=q_act_mm.copy(),
            psi=psi,
            tip_mm=T[:3, 3].copy(),
            R_tip=T[:3, :3].copy(),
            tension_N=np.asarray(tension, dtype=float),
        )

    def sensor_orientation(self, joint: int) -> np.ndarray:
        """R_world_sensor (3x3) of the attitude sensor on joint ``joint``'s end (0-based): the
        world orientation of the joint-end frame times the sensor's mount (sensor -> joint end).

        From the published state's joint angles (the same chain :meth:`_solve` computes), so a
        state solved elsewhere (the lock-step rig's truth worker) gives the same orientations."""
        state = self.state
        with self._lock:
            of, ends = self._ends
            if of is not state:
                ends, _T = self._end_rotations(state.psi)
                self._ends = (state, ends)
        return self.R_world_base @ ends[joint] @ self.mounts[joint]
