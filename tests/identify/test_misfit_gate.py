"""The misfit gate (cdcr_ctl.identify.gate): a fit that does not explain its data writes nothing.

Acceptance 3 of issue #17: a world with an effect the identified model lacks never yields a
silently written overlay. The world here has a drive scale error (cable 1 moves 15 % more than
its drive reports, cable 2 10 % less): nothing the sweep's fit has a parameter for. The fit runs
through the same function the ``identify`` command calls, on a synthetic sweep (load-cell noise
0.02 N, tracker 0.05 mm); its solver gets few evaluations to keep the test fast, which can only
leave the residual larger, so the refusal does not depend on them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import synth

from cdcr_ctl.cli.identify import fit_and_write
from cdcr_ctl.identify.estimator import FitOptions
from cdcr_ctl.identify.gate import MISFIT_FACTOR, MisfitError, judge_fit
from cdcr_ctl.identify.sweep import SweepSpec, calibration_sweep
from cdcr_ctl.model.cc_disk.effects import TransmissionScale
from cdcr_ctl.model.cc_disk.params import Effects

SPEC = SweepSpec(
    betas_deg=(0.0, 120.0),
    theta_step_deg=25.0,
    approach_step_deg=0.0,
    dwell_s=0.6,
    start_dwell_s=0.6,
)
FAST = FitOptions(max_nfev=8)


def test_judge_fit_accepts_noise_and_refuses_a_residual_above_it():
    rms = {"tip": 0.05, "cell": 0.02}
    ok = judge_fit(1.2, rms, rms)
    assert ok.ok and ok.reasons == []
    limit = MISFIT_FACTOR**2
    assert judge_fit(0.99 * limit, rms, rms).ok
    bad = judge_fit(1.01 * limit, rms, rms)
    assert not bad.ok and "x the noise" in bad.reasons[0]
    assert "discrepancy" in bad.message("runs/x", "rig.yaml")
    assert not judge_fit(math.nan, rms, rms).ok


def test_judge_fit_refuses_a_fit_that_trades_one_measurement_for_another():
    before = {"tip": 0.06, "cell": 0.13}
    worse = judge_fit(2.0, before, {"tip": 0.5, "cell": 0.01}, {"tip": 0.15})
    assert not worse.ok and worse.reasons[0].startswith("tip residual grew")
    # a growth that stays inside the noise does not count
    assert judge_fit(2.0, {"tip": 0.01}, {"tip": 0.05}, {"tip": 0.15}).ok


def test_a_world_with_an_effect_the_model_lacks_writes_no_overlay(tmp_path: Path):
    params = synth.perturbed_world(seed=7, pulleys=False).params
    effects = Effects(
        geometry="chord", capstan_points=25, actuator=(TransmissionScale((1.15, 0.9, 1.0)),)
    )
    run = synth.write_run(
        tmp_path / "sweep",
        calibration_sweep(1, SPEC),
        synth.World(params, effects),
        samples_per_dwell=8,
        seed=3,
    )
    out = tmp_path / "identification"
    stale = out / "identified.yaml"
    out.mkdir()
    stale.write_text("robot: {}\n")  # an overlay from an earlier fit must not survive either
    with pytest.raises(MisfitError) as exc:
        fit_and_write(synth.RIG_CONFIG, [run], out, FAST, fit_pulleys="off")
    msg = str(exc.value)
    assert "No parameters written" in msg and f"discrepancy {run}" in msg
    assert not stale.exists()
    rep = json.loads((out / "identification.json").read_text())
    assert rep["verdict"]["ok"] is False
    assert rep["verdict"]["misfit_ratio"] > MISFIT_FACTOR
