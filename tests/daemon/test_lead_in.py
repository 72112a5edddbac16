"""The daemon's lead-in move keeps cables within half their speed limit on every design."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon.service import LEAD_IN_CABLE_FRACTION, Daemon

CONFIG = Path(__file__).resolve().parents[2] / "config"


def _daemon_like(cfg_name: str, psi_now: np.ndarray) -> SimpleNamespace:
    cfg = load_rig_config(CONFIG / cfg_name)
    return SimpleNamespace(
        cfg=cfg,
        model=build_model(cfg),
        loop=SimpleNamespace(psi_cmd=psi_now),
        new_trajectory=tj,
    )


def _peak_cable_speed(model, traj: tj.Trajectory) -> float:
    q = np.array([model.q_nominal(p) for p in traj.psi])
    return float(np.max(np.abs(np.diff(q, axis=0)) / np.diff(traj.t_s)[:, None]))


def test_ujoint_lead_in_is_slowed_to_the_cable_limit() -> None:
    # From a 6 deg sub-joint tilt back to straight: at the default pi/10 rad/s the universal
    # joint arm's cables would run several times faster than its limit.
    d = _daemon_like("yang2022-sim.yaml", np.array([[math.radians(6), 0.0]] * 2))
    target = tj.Trajectory([0.0, 1.0], np.zeros((2, 2, 2)), "hold", "<test>")
    fast = tj.with_lead_in(d.loop.psi_cmd, target)
    limit = d.cfg.limits.cable_velocity_mm_s
    assert _peak_cable_speed(d.model, fast) > limit
    slow = Daemon._with_lead_in(d, target)
    assert slow.duration_s > fast.duration_s
    assert _peak_cable_speed(d.model, slow) <= LEAD_IN_CABLE_FRACTION * limit * 1.01
    np.testing.assert_allclose(slow.psi[0], d.loop.psi_cmd)
    np.testing.assert_allclose(slow.psi[-1], target.psi[-1])


def test_disk_arm_lead_in_keeps_the_default_speed() -> None:
    d = _daemon_like("qi2023-sim.yaml", np.array([[0.3, 0.0]]))
    target = tj.Trajectory([0.0, 1.0], np.zeros((2, 1, 2)), "hold", "<test>")
    lead = Daemon._with_lead_in(d, target)
    assert lead.duration_s == pytest.approx(tj.with_lead_in(d.loop.psi_cmd, target).duration_s)
