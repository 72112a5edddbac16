"""Identification on synthetic data with known parameters (Qi et al. 2023 eq. 38 and beyond).

A made-up truth (:func:`synth.perturbed_world`: mu, EA, EI off the nominal config by 20-35 %,
pretensions by up to 10 %; pulleys nominal; the mount tilted by :data:`TILT_DEG`) is driven
through a calibration sweep with the controller's uncompensated commands; the log gets load-cell
noise 0.02 N and tracker noise 0.05 mm. The fit sees only the nominal config and the log. The
capstan tables are coarser than the controller's (25 points) in truth and fit alike, to keep the
test fast.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import synth
import yaml

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model, loadcell_locations, robot_params
from cdcr_ctl.identify.dwell import extract_dwells
from cdcr_ctl.identify.estimator import identify
from cdcr_ctl.identify.gate import judge_identification
from cdcr_ctl.identify.parameters import plan_parameters, tilted_gravity
from cdcr_ctl.identify.pipeline import overlay_text
from cdcr_ctl.identify.sweep import SweepSpec, calibration_sweep
from cdcr_ctl.model.cc_disk.effects import with_cable_play
from cdcr_ctl.model.cc_disk.identification import get_value
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.runlog import load_run

EFFECTS = Effects(geometry="chord", capstan_points=25)
#: Lost motion of the made-up truth per cable (mm): 0.2-0.4 mm, as the default simulated world.
PLAY_MM = (0.25, 0.4, 0.3)
#: Mount tilt of the made-up truth (deg, about base x and y): the config believes it upright.
TILT_DEG = (6.0, -15.0)
SPEC = SweepSpec(theta_step_deg=25.0, approach_step_deg=0.0, dwell_s=0.6, start_dwell_s=0.6)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    params = synth.with_play(synth.perturbed_world(seed=7, pulleys=False).params, PLAY_MM)
    g = tilted_gravity(params.gravity_mm_s2, TILT_DEG)
    params = dataclasses.replace(params, gravity_mm_s2=tuple(float(v) for v in g))
    world = synth.World(params, with_cable_play(params, EFFECTS))
    run_dir = tmp_path_factory.mktemp("ident") / "sweep"
    synth.write_run(run_dir, calibration_sweep(1, SPEC), world, samples_per_dwell=8, seed=3)
    cfg = load_rig_config(synth.RIG_CONFIG)
    nominal = build_model(cfg).params
    locs = loadcell_locations(cfg)
    points, _ = extract_dwells(load_run(run_dir))
    # The pulleys are the nominal ones here and not fitted: each trial pulley alpha rebuilds
    # the capstan tables, which would make this test slow (the experiments command fits them).
    fps, fixed = plan_parameters(nominal, points, locs, fit_pulleys="off")
    res = identify(nominal, EFFECTS, points, locs, fps, fixed)
    return world, res, cfg


def _truth(world, est) -> float:
    return get_value(world.params, est.parameter.refs[0]) / est.parameter.scales[0]


@pytest.mark.parametrize("kind", ["mu", "EA", "EI", "pretension"])
def test_known_parameters_recovered(fitted, kind):
    world, res, _ = fitted
    ests = [e for e in res.estimates if e.parameter.kind == kind]
    assert ests, f"no {kind} was fitted"
    for e in ests:
        truth = _truth(world, e)
        # The nominal start is 20-35 % off; the fit must land within 3 % (acceptance: 10 %).
        assert e.value == pytest.approx(truth, rel=0.03), e.name
        assert abs(e.nominal / truth - 1.0) > 0.05 or kind == "pretension"
        # The 95 % interval is honest: the truth lies within a few standard errors.
        assert abs(e.value - truth) < 5.0 * e.std + 1e-3 * truth, e.name


def test_lost_motion_recovered(fitted):
    """The dead zone of every cable (nominal 0) is found from the direction-dependent
    compatibility residual (Yang et al. 2022 eq. 13-17)."""
    world, res, _ = fitted
    ests = [e for e in res.estimates if e.parameter.kind == "backlash"]
    assert len(ests) == len(PLAY_MM)
    for e in ests:
        truth = _truth(world, e)
        assert e.nominal == 0.0
        # 0.02 mm: a tenth of the smallest play, and 8 x the tracker noise over the routing
        # radius ratio the compatibility rows see (0.05 mm tip noise / sqrt(dwells)).
        assert abs(e.value - truth) < 0.02, e.name


def test_mount_tilt_recovered(fitted):
    """The gravity direction is fitted with the normal identification (the config says -z,
    the truth is turned by TILT_DEG): the disk weights' moment in the moment balance."""
    world, res, _ = fitted
    tilts = sorted(
        (e for e in res.estimates if e.parameter.kind == "gravity_tilt"),
        key=lambda e: e.parameter.index,
    )
    assert [e.name for e in tilts] == ["mount.tilt_x_deg", "mount.tilt_y_deg"]
    for e, truth in zip(tilts, TILT_DEG, strict=True):
        assert e.nominal == 0.0
        # 1.5 deg: the disks weigh 4.5 g in all, their moment is ~2 N mm at the straight pose,
        # and the moment rows' noise (0.02 N x 6 mm routing radius per dwell) resolves its
        # direction to about a degree over this coarse sweep's ~20 dwells.
        assert abs(e.value - truth) < 1.5, e.name
    g_fit = np.asarray(res.fitted.gravity_mm_s2)
    g_true = np.asarray(world.params.gravity_mm_s2)
    assert np.linalg.norm(g_fit) == pytest.approx(np.linalg.norm(g_true), rel=1e-9)
    angle = math.degrees(math.acos(g_fit @ g_true / (np.linalg.norm(g_fit) ** 2)))
    assert angle < 2.0


def test_fit_explains_the_data_and_reports_what_stays_nominal(fitted):
    _, res, _ = fitted
    assert res.rms_after["tip"] < 0.1 * res.rms_before["tip"] + 0.02
    assert res.rms_after["cell"] < 0.2 * res.rms_before["cell"]
    assert any(f.name == "pulleys.alpha" for f in res.fixed)
    assert 0.3 < res.chi2_reduced < 5.0
    # the misfit gate lets a fit through that explains its data
    assert judge_identification(res).ok


def test_overlay_loads_back_into_the_rig_config(fitted, tmp_path: Path):
    _, res, cfg = fitted
    ov = tmp_path / "identified.yaml"
    ov.write_text(overlay_text(cfg, res, ["synthetic"]))
    assert "95 % CI" in ov.read_text()
    rig = tmp_path / "rig.yaml"
    rig.write_text(yaml.safe_dump({"extends": str(synth.RIG_CONFIG), "overlays": [str(ov)]}))
    params = robot_params(load_rig_config(rig).robot)
    # the fitted mount tilt comes back as the config's gravity vector (0.01 mm/s^2 rounding)
    np.testing.assert_allclose(params.gravity_mm_s2, res.fitted.gravity_mm_s2, atol=0.01)
    for e in res.estimates:
        for ref, sc in zip(e.parameter.refs, e.parameter.scales, strict=True):
            assert get_value(params, ref) == pytest.approx(e.value * sc, rel=1e-4), e.name


def test_sweep_is_the_papers_and_dwells_carry_the_friction_direction(tmp_path: Path):
    sweep = calibration_sweep(1)
    up = [d for d in sweep.dwells if d.leg == "up"]
    down = [d for d in sweep.dwells if d.leg == "down"]
    betas = sorted({round(np.degrees(d.beta_rad)) for d in up})
    assert betas == [0, 120, 240]
    assert sorted({round(np.degrees(d.theta_rad)) for d in up}) == list(range(40, 91, 5))
    assert len(up) == 3 * 11 and len(down) == 3 * 10
    # Dwells from a log: on the up leg of beta = 0 cable 1 is pulled in (+1) and cables 2, 3
    # pay out (-1); on the way down all flip; the first dwell after a reversal is uncertain.
    world = synth.World(synth.perturbed_world(seed=1).params, EFFECTS)
    small = calibration_sweep(1, SweepSpec(betas_deg=(0.0,), theta_step_deg=25.0, dwell_s=0.6))
    run_dir = synth.write_run(tmp_path / "r", small, world, samples_per_dwell=6)
    pts, _ = extract_dwells(load_run(run_dir))
    assert len(pts) == len(small.dwells)
    legs = [d.leg for d in small.dwells]
    first_down = legs.index("down")
    top = pts[first_down - 1]
    assert top.s == (1.0, -1.0, -1.0) and all(top.s_known)
    rev = pts[first_down]
    assert rev.s == (-1.0, 1.0, 1.0) and not any(rev.s_known)
    # tensions and tip are averaged: the pulled cable carries more than its pretension
    assert top.tension_N[0] > 2.0 * top.tension_N[1]
    assert np.all(np.isfinite(top.tip_mm)) and top.tip_mm[0] > 20.0


def test_play_state_is_used_only_once_the_drive_ranged_over_the_gap(fitted):
    """A run may start with its cables anywhere in their play (a sweep plane that follows
    another in the same session): the compatibility rows of a cable count only after its drive
    has ranged over more than PLAY_SETTLE_MM since the run's start (the play operator forgets
    its start state once the range exceeds the width). Measured: three sweep planes run one
    after another on one simulated rig fitted with reduced chi^2 179 (refused) when every run
    was assumed to start centred, 6.3 with this rule."""
    from cdcr_ctl.identify.estimator import FitOptions, _Problem
    from cdcr_ctl.identify.problem import PLAY_SETTLE_MM

    _, res, cfg = fitted
    nominal = build_model(cfg).params
    locs = loadcell_locations(cfg)
    fps, _ = plan_parameters(nominal, res.points, locs, fit_pulleys="off")
    prob = _Problem(nominal, EFFECTS, res.points, locs, fps, FitOptions())
    known = np.array(prob.play_known)
    q = np.array([p.q_act_mm for p in res.points])
    assert not known[0].any()  # the run's first dwell: the play state is unknown
    assert known[-1].all()
    for k in range(q.shape[1]):
        first = int(np.argmax(known[:, k]))
        assert known[first:, k].all()  # once known, known for the rest of the run
        assert np.ptp(q[: first + 1, k]) >= PLAY_SETTLE_MM
        assert np.ptp(q[:first, k]) < PLAY_SETTLE_MM
    compat = [(j, k) for j, r in enumerate(prob.rows) for kind, k in r if kind == "compat"]
    assert compat and all(known[j, k] for j, k in compat)
