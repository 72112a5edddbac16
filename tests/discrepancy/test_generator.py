"""The run generator (scripts/make_discrepancy_runs.py): how far it bends and what it commands.

Level: system (the generator's trajectory rules on the real rig configs; one short run through the
truth stepping and the run-log writer). The rules are physical: Qi et al. 2023 bend to 90 deg,
the rig's limits are never exceeded, and the command is the control loop's.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_cc_disk_model
from cdcr_ctl.runlog import load_run

ROOT = Path(__file__).resolve().parents[2]
EFFECTS = ROOT / "config" / "sim" / "effects"


def _q_max(model, traj) -> float:
    t = np.arange(0.0, traj.duration_s, 0.05)
    return max(float(np.max(np.abs(model.q_nominal(traj.sample(ti))))) for ti in t)


def test_default_bend_is_the_papers_90_degrees_within_the_rig_limits(gen):
    cfg = load_rig_config(ROOT / "config" / "qi2023.yaml")
    model = build_cc_disk_model(cfg)
    traj, bend, how = gen.trajectory_within_limits(cfg, model, "rich", 30.0, None, 4)
    # 0.9 x limits.bend_rad = 1.575 rad > pi/2: the paper's range is kept
    assert bend == pytest.approx(math.pi / 2) and "limits.bend_rad" in how
    theta = traj.psi[..., 0]
    assert 0.6 * bend - 1e-9 <= theta.max() <= bend + 1e-9  # first direction: U(0.6, 1) x bend
    # a given bend is used as it is
    _, b2, how2 = gen.trajectory_within_limits(cfg, model, "rich", 30.0, 0.7, 4)
    assert b2 == 0.7 and how2 == "given"


def test_default_bend_shrinks_until_the_cables_stay_within_their_limit(gen):
    cfg = load_rig_config(ROOT / "config" / "qi2023.yaml")
    tight = cfg.model_copy(
        update={"limits": cfg.limits.model_copy(update={"cable_displacement_mm": [-3.0, 3.0]})}
    )
    model = build_cc_disk_model(tight)
    traj, bend, how = gen.trajectory_within_limits(tight, model, "rich", 30.0, None, 4)
    assert bend < math.pi / 2 and how.startswith("reduced")
    assert _q_max(model, traj) <= gen.LIMIT_SHARE * 3.0


def test_commands_are_the_loops_in_the_rig_configs_compensation_mode(gen, tmp_path):
    run = gen.make_run(EFFECTS / "none.yaml", tmp_path, duration_s=6.0, rate_hz=50.0, seed=3)
    r = load_run(run)
    assert r.metadata["compensation"] == "model"  # qi2023.yaml control.compensation
    assert r.metadata["extra"]["compensation_rule"] == "rig config"
    q_nom, q_cmd, q_act = r.q_nominal(), r.q_cmd(), r.q_act()
    # model compensation adds the cable stretch: the pulled cable gets more than nominal
    assert np.max(q_cmd - q_nom) > 0.02
    # the drives reach last cycle's command in whole counts (1238.6 counts/mm)
    assert np.allclose(q_act[1:], np.round(q_cmd[:-1] * 1238.6) / 1238.6, atol=1e-9)
    # the supervisor's velocity limit holds at every cycle (40 mm/s)
    assert np.max(np.abs(np.diff(q_cmd, axis=0))) <= 40.0 / 50.0
    off = gen.make_run(
        EFFECTS / "none.yaml",
        tmp_path,
        duration_s=2.0,
        rate_hz=50.0,
        seed=3,
        name="off",
        compensation="off",
    )
    r_off = load_run(off)
    assert r_off.metadata["compensation"] == "off"
    assert np.array_equal(r_off.q_cmd(), r_off.q_nominal())


def test_compensation_the_supervisor_would_halt_falls_back_to_off(gen):
    """Three segments bent far: the inverse model steps a cable by its friction dead zone at a
    reversal (more than the 40 mm/s limit allows in a cycle); the daemon would halt that run."""
    cfg = load_rig_config(ROOT / "config" / "three_segment_example.yaml")
    model = build_cc_disk_model(cfg)
    traj, _, _ = gen.trajectory_within_limits(cfg, model, "rich", 20.0, None, 11)
    mode, why = gen.compensation_mode(cfg, model, traj, 100.0, None)
    assert mode == "off" and "mm/s" in why
    assert gen.compensation_mode(cfg, model, traj, 100.0, "model") == ("model", "given")
