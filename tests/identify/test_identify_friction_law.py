"""``cdcr-ctl identify`` fits the disk friction under the rig config's ``robot.friction_law``, the
law the controller's compensation applies (cdcr_ctl/model/cc_disk/friction_law.py).

The world is config/sim/effects/friction_law.yaml: disk friction whose log tension ratio grows
with the square of the wrap (the simulator's ``wrap_power`` law, exponent 2) and mu_disk
0.52/0.62/0.56, twice the config's. A short calibration sweep (three planes, theta 40 and 90
deg: six dwells) is fitted twice: under ``wrap_exponent: 2.0`` (the world's law: the model is
exact, so the fit is unbiased and its error is the noise's, a few of its standard errors at
most) and under the capstan law (mu refitted under the wrong law: biased far outside its own
interval, and the misfit shows in the reduced chi^2).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import synth

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import (
    build_cc_disk_model,
    build_model,
    friction_law,
    loadcell_locations,
)
from cdcr_ctl.identify.dwell import extract_dwells
from cdcr_ctl.identify.estimator import identify
from cdcr_ctl.identify.parameters import plan_parameters
from cdcr_ctl.identify.pipeline import identify_runs, overlay_text, report_dict, summary_table
from cdcr_ctl.identify.problem import dwell_transfer
from cdcr_ctl.identify.sweep import SweepSpec, calibration_sweep
from cdcr_ctl.model.cc_disk.effects import with_cable_play
from cdcr_ctl.model.cc_disk.friction_law import LawTransfer
from cdcr_ctl.runlog import load_run

WORLD = synth.ROOT / "config" / "sim" / "effects" / "friction_law.yaml"
SPEC = SweepSpec(theta_step_deg=50.0, approach_step_deg=0.0, dwell_s=0.6, start_dwell_s=0.6)
#: Standard errors within which a fit under the world's own law recovers it (two-sided
#: probability 0.27 % per parameter of exceeding it for a Gaussian estimate).
N_SIGMA = 3.0


def _rig(tmp_path: Path, law: str) -> Path:
    p = tmp_path / "rig.yaml"
    p.write_text(f"extends: {synth.RIG_CONFIG}\nrobot:\n  friction_law: {law}\n")
    return p


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    truth = synth.truth_world(WORLD)
    world = synth.World(
        truth.params, with_cable_play(truth.params, truth.effects), wrap_exponent=2.0
    )
    tmp = tmp_path_factory.mktemp("law")
    run = synth.write_run(
        tmp / "run",
        calibration_sweep(1, SPEC),
        world,
        samples_per_dwell=8,
        tension_noise_N=0.02,
        tip_noise_mm=0.02,
        seed=3,
    )
    return truth, run, tmp


@pytest.fixture(scope="module")
def under_law(sweep):
    _, run, tmp = sweep
    rig = _rig(tmp, "{wrap_exponent: 2.0}")
    return identify_runs(load_rig_config(rig), [run], fit_pulleys="off", source=str(rig)), rig


def _mu(ident) -> list:
    return [e for e in ident.estimates if e.parameter.kind == "mu"]


def test_the_fit_under_the_configs_law_recovers_the_worlds_mu_and_says_so(sweep, under_law):
    truth, _, _ = sweep
    ident, rig = under_law
    mus = _mu(ident)
    assert len(mus) == 3
    for e in mus:
        true = truth.params.cables[e.parameter.index].mu_disk
        assert abs(e.value - true) <= N_SIGMA * e.std, (e.name, e.value, e.std, true)
    line = f"disk friction law: robot.friction_law wrap exponent 2 (from {rig})"
    assert ident.friction_law_text == line
    assert summary_table(ident).splitlines()[0] == line
    rep = report_dict(ident)["friction_law"]
    assert (rep["wrap_exponent"], rep["breakaway"], rep["source"]) == (2.0, 0.0, str(rig))
    assert f"# {line}\n" in overlay_text(load_rig_config(rig), ident, ["run"])


def test_the_capstan_law_refits_mu_biased_beyond_its_interval(sweep, under_law):
    """mu alone refitted under the capstan law (the config's default): the world's mu lies
    outside every cable's 95 % interval, and the reduced chi^2 is >10x the right law's."""
    truth, run, _ = sweep
    cfg = load_rig_config(synth.RIG_CONFIG)
    assert friction_law(cfg.robot) is None
    model = build_model(cfg)
    locs = loadcell_locations(cfg)
    points, _ = extract_dwells(load_run(run))
    fps, _ = plan_parameters(model.params, points, locs, fit_pulleys="off")
    capstan = identify(
        model.params, model.effects, points, locs, [f for f in fps if f.kind == "mu"]
    )
    assert capstan.friction_law_text is None
    for e in _mu(capstan):
        true = truth.params.cables[e.parameter.index].mu_disk
        assert not e.ci95[0] <= true <= e.ci95[1], (e.name, e.value, e.ci95, true)
    assert capstan.chi2_reduced > 10.0 * under_law[0].chi2_reduced


def test_the_dwell_chain_is_the_controllers_at_rest(tmp_path):
    """identify's chain for a config with a law is the controller's chain of the same law with
    every cable at rest (the speed factor m(0) = 1 + b): the same class and the same factors,
    computed by the same code (equal to rounding, 1e-12 relative)."""
    cfg = load_rig_config(
        _rig(tmp_path, "{wrap_exponent: 1.5, viscous_s_per_mm: 0.2, breakaway: 0.3}")
    )
    ctrl = build_cc_disk_model(cfg)
    ft = dwell_transfer(ctrl.params, ctrl.effects, friction_law(cfg.robot))
    assert isinstance(ft, LawTransfer) and isinstance(ctrl.transfer, LawTransfer)
    mu0 = [c.mu_disk * 1.3 for c in ctrl.params.cables]
    np.testing.assert_allclose(ft._mu, mu0, rtol=1e-12)
    xs = [0.9 * math.cos(0.7), 0.9 * math.sin(0.7)]
    s = [1.0, -1.0, 1.0]
    Pa, Pb = ft.pose(xs), ctrl.transfer.pose(xs)
    np.testing.assert_allclose(ft.factors(Pa, s)[1], ctrl.transfer.factors(Pb, s)[1], rtol=1e-12)
