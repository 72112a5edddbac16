"""System: `cdcr-ctl demo --design vertebra --quick --lockstep` - the simulated vertebra rig (nine
EPOS nodes, the attitude sensors through the WitMotion parser, the tracker) and the daemon in
lock-step (one process, simulated time; the subject is the results, not the timing),
the joystick end-following session (planned offline, run as a timed trajectory) without and
with the sag compensation."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from cdcr_ctl.runlog import load_run


@pytest.mark.slow
@pytest.mark.multicore
@pytest.mark.timeout(300)
def test_vertebra_demo_completes_both_runs_and_the_sag_compensation_reduces_the_tip_error(
    tmp_path,
):
    out = tmp_path / "out"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "cdcr_ctl",
            "demo",
            "--design",
            "vertebra",
            "--quick",
            "--lockstep",
            "--no-plots",  # the subject is the runs' results; test_demo checks the plots
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=280,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    (session,) = out.iterdir()
    rows = json.loads((session / "results.json").read_text())
    by = {(r["experiment"], r["compensation"]): r for r in rows}
    assert set(by) == {("end_following", "off"), ("end_following", "model")}
    assert all(r["state"] == "completed" and r["samples"] > 500 for r in rows)
    # No attempt tripped (the demo would have kept a tripped run's log and run it again): the
    # velocity limit holds with the compensation's rate on top of the plan, and the tracked tip
    # stays within the divergence limit of the model's.
    runs = sorted((session / "runs").iterdir())
    assert len(runs) == 2, [p.name for p in runs]
    for run_dir in runs:
        run = load_run(run_dir)
        assert run.ended["outcome"] == "completed", run.ended["reason"]
        assert {"q_cmd", "q_act", "tip"} <= set(run.groups)
    # The sag compensation (statics of the nominal model) takes out part of the gravity sag the
    # kinematic control leaves (the world's arm is softer and heavier than the model's).
    off = by[("end_following", "off")]["mean_mm"]
    model = by[("end_following", "model")]["mean_mm"]
    assert model < off, (off, model)
