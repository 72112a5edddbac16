"""The demo's experiments per design (``cdcr-ctl demo``): each function returns the timed
trajectories (name -> :class:`~cdcr_ctl.control.trajectory.Trajectory`) of its design's demo for a
loaded rig config; the design registry names them (:attr:`cdcr_ctl.config.registry.Design.demo`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cdcr_ctl.config.designs import plan_follow_offline, ujoint_arm
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.model.ujoint import UJointModel
from cdcr_ctl.model.vertebra.follow import paper_session


def cc_disk(rig_cfg: Any, quick: bool) -> dict[str, Any]:
    """Qi et al. 2023 section 5: the planar bend and the spatial circle.

    ``quick``: a smaller bend at 0.6 rad/s that returns to straight (5.0 s; the next run then
    starts without the daemon's lead-in back from the bent pose, at pi/10 rad/s), and the
    circle's sweep at 1 rad/s with its lead-in and lead-out at 0.6 rad/s (10.4 s)."""
    if quick:
        return {
            "planar_bend": tj.planar_bend(theta_max_rad=1.2, rate_rad_s=0.6, back=True, hold_s=1.0),
            "circle": tj.spatial_circle(
                theta_rad=0.7854, phi_rate_rad_s=1.0, lead_in_rate_rad_s=0.6
            ),
        }
    return {
        "planar_bend": tj.planar_bend(theta_max_rad=1.5708, back=False, hold_s=1.0),
        "circle": tj.spatial_circle(theta_rad=0.7854, phi_rate_rad_s=0.314),
    }


def ujoint(rig_cfg: Any, quick: bool) -> dict[str, Any]:
    """Yang et al. 2022 section 4.2: go-and-return 0 -> 6 deg -> 0 of every sub-joint."""
    # Yang et al. 2022 section 4.2: [0, 6 deg, 0, 6 deg] and back at uniform speed, i.e. a
    # sub-joint tilt of 6 deg towards x (phi = 0) in both segments. The rate puts the
    # fastest cable (c22 of yang2022.yaml: ~8 mm per degree), section 3's compensation
    # included, at a share of the rig's velocity limit: 40 % (~1 deg/s) for the full demo,
    # 60 % (~1.5 deg/s) with --quick. The rest is room for the compensation's steps, which
    # UJointModel rate-limits into it (dead zone and flipped deformation at the reversal,
    # up to ~4.7 mm on c11), and margin for a busy PC, where a simulator or daemon that
    # waits for the CPU leaves the arm behind the command.

    theta = math.radians(6.0)
    ideal = UJointModel(ujoint_arm(rig_cfg))  # section 3 without the loop's rate limit
    state, q_nom, q_cmd = ideal.new_state(), [], []
    for t in np.linspace(0.0, theta, 61):
        psi = np.array([[t, 0.0], [t, 0.0]])
        q_nom.append(ideal.q_nominal(psi))
        q_cmd.append(ideal.q_command(psi, q_nom[-1], state, "model", None))
    step = theta / 60
    # mm per rad of tilt; the compensated command from its third sample on (the first
    # motion steps it by the dead zone, a step the rate limit takes care of)
    slope = max(
        float(np.abs(np.diff(q_nom, axis=0)).max()) / step,
        float(np.abs(np.diff(q_cmd[2:], axis=0)).max()) / step,
    )
    rate = (0.6 if quick else 0.4) * rig_cfg.limits.cable_velocity_mm_s / slope
    return {"go_and_return": tj.go_and_return(2, theta, rate, 0.0)}


def vertebra(rig_cfg: Any, quick: bool) -> dict[str, Any]:
    """The fuel-tank paper's joystick end-following session (Fig. 12), planned offline;
    ``quick``: the session at ``scale`` 0.3 (:func:`paper_session`: shorter bend moves and
    waits; both "forward" follows are still made)."""

    t, psi, planner = plan_follow_offline(rig_cfg, paper_session(scale=0.3 if quick else 1.0))
    # Back to straight in the planner's synchronised steps (within the planned speed), so the
    # next run starts where this one did instead of behind the daemon's lead-in move (whose
    # speed is set in joint space: three joints together drive a distal cable past its
    # limit).
    planner.set_targets(np.zeros_like(psi[-1]))
    t_back, psi_back, _ = plan_follow_offline(rig_cfg, [], planner)
    t = np.concatenate((t, t[-1] + t_back[1:]))
    psi = np.concatenate((psi, psi_back[1:]))
    return {"end_following": tj.Trajectory(t, psi, "end_following", "<joystick session>")}
