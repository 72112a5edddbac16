"""Friction states of dwells when the play is wider than the sweep's step between dwells.

After a reversal the drive crosses its cable's play b before the cable turns
(:mod:`cdcr_ctl.model.shared.deadzone`); with b of 2.0-2.5 mm and a sweep of 10 deg steps (0.7 mm of
drive per step on the bending cable, 0.3 mm on the others) the cable is still in its gap two to
eight dwells after the reversal, so its friction has not turned there. The rule of
:mod:`cdcr_ctl.identify.dwell` leaves those states unknown until the drive came back by the play
(the configured one, then the fitted one). Measured on this world with the states of "the second
dwell after a reversal" for every cable: the plays right within 1.1 %, mu 50-75 % low, refused
(reduced chi^2 337); with this rule reduced chi^2 0.80, accepted.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import synth

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model, loadcell_locations
from cdcr_ctl.identify.dwell import extract_dwells, with_play
from cdcr_ctl.identify.estimator import FitOptions, identify
from cdcr_ctl.identify.gate import judge_identification
from cdcr_ctl.identify.parameters import plan_parameters
from cdcr_ctl.identify.sweep import SweepSpec, calibration_sweep
from cdcr_ctl.model.cc_disk.effects import TransmissionScale, with_cable_play
from cdcr_ctl.model.cc_disk.identification import get_value
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.runlog import load_run

EFFECTS = Effects(geometry="chord", capstan_points=25)
#: Lost motion per cable (mm): wider than two of the sweep's steps on every cable.
PLAY_MM = (2.0, 2.5, 2.2)
SPEC = SweepSpec(
    theta_step_deg=10.0,
    approach_step_deg=0.0,
    dwell_s=0.6,
    start_dwell_s=0.6,
)


def _fit(tmp_path, actuator=(), options=None):
    params = synth.with_play(synth.perturbed_world(seed=7, pulleys=False).params, PLAY_MM)
    eff = with_cable_play(params, EFFECTS)
    eff = dataclasses.replace(eff, actuator=(*eff.actuator, *actuator))
    world = synth.World(params, eff)
    run = synth.write_run(
        tmp_path / "sweep", calibration_sweep(1, SPEC), world, samples_per_dwell=8, seed=3
    )
    cfg = load_rig_config(synth.RIG_CONFIG)
    nominal = build_model(cfg).params
    locs = loadcell_locations(cfg)
    points, _ = extract_dwells(load_run(run))
    fps, fixed = plan_parameters(nominal, points, locs, fit_pulleys="off")
    return world, points, identify(nominal, EFFECTS, points, locs, fps, fixed, options)


def test_states_stay_unknown_until_the_drive_came_back_by_the_play(tmp_path):
    world = synth.World(synth.with_play(synth.perturbed_world(seed=7).params, PLAY_MM), EFFECTS)
    run = synth.write_run(
        tmp_path / "r", calibration_sweep(1, SPEC), world, samples_per_dwell=4, seed=3
    )
    pts, _ = extract_dwells(load_run(run))
    wide = with_play(pts, PLAY_MM)
    q = np.array([p.q_act_mm for p in pts])
    for k in range(3):
        for j in range(2, len(pts)):
            if pts[j].s_known[k] and not wide[j].s_known[k]:
                # unknown with the play only: the drive had not come back by b at the dwell
                # before, counted from the last reversal of this cable
                d = np.sign(q[j, k] - q[j - 1, k])
                # (the run's first motion counts as a reversal: the start state is unknown)
                rev = max(
                    (i for i in range(1, j) if np.sign(q[i, k] - q[i - 1, k]) != d), default=1
                )
                assert d * (q[j - 1, k] - q[rev - 1, k]) < PLAY_MM[k]
        # with the play some states right after reversals are unknown that were known before
        assert sum(p.s_known[k] and not w.s_known[k] for p, w in zip(pts, wide, strict=True))
    # no play: the rule of the second dwell after a reversal
    assert [p.s_known for p in with_play(pts, (0.0, 0.0, 0.0))] == [p.s_known for p in pts]


@pytest.mark.timeout(600)
def test_a_play_wider_than_the_step_is_fitted_and_accepted(tmp_path):
    world, _, res = _fit(tmp_path)
    assert res.stages[0].startswith("friction states re-assigned for the fitted play")
    verdict = judge_identification(res)
    assert verdict.ok, verdict.reasons
    for e in res.estimates:
        if e.parameter.kind == "gravity_tilt":
            # the truth is upright; the 4.5 g of disks resolve the mount to about a degree
            # over a sweep's dwells (tests/identify/test_identify_fit.py), 3 deg is ~3 sigma
            assert abs(e.value) < 3.0, e.name
            continue
        truth = get_value(world.params, e.parameter.refs[0]) / e.parameter.scales[0]
        if e.parameter.kind == "backlash":
            # 0.02 mm: the tracker noise 0.05 mm over sqrt(dwells), as the narrow-play test
            assert abs(e.value - truth) < 0.02, e.name
        else:
            # the narrow-play world's 3 % (tests/identify/test_identify_fit.py)
            assert e.value == pytest.approx(truth, rel=0.03), e.name


def test_a_wide_play_world_the_model_cannot_represent_is_still_refused(tmp_path):
    """The same world with a drive scale error (cable 1 moves 15 % more than its drive says,
    cable 2 10 % less; tests/identify/test_misfit_gate.py): no parameter of the fit explains
    it, and re-assigning the states for the fitted play does not hide it. Few solver
    evaluations (fast): they can only leave the residual larger."""
    scale = (TransmissionScale((1.15, 0.9, 1.0)),)
    _, _, res = _fit(tmp_path, scale, FitOptions(max_nfev=8))
    assert not judge_identification(res).ok
