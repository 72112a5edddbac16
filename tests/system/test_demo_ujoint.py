"""System: `cdcr-ctl demo --design ujoint --quick --lockstep` - the simulated universal-joint rig
(six simulated EPOS nodes, the tracker) and the daemon in lock-step (one process, simulated time;
the subject is the results, not the timing), Yang et al. 2022's go-and-return without
and with section 3's compensation."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.analysis import tip_from_psi_for_run
from cdcr_ctl.config import load_rig_config
from cdcr_ctl.runlog import load_run

SIM_RIG = Path(__file__).resolve().parents[2] / "config" / "yang2022-sim.yaml"


@pytest.mark.slow
@pytest.mark.multicore
@pytest.mark.timeout(300)
def test_ujoint_demo_completes_both_runs_and_the_compensation_reduces_the_tip_error(tmp_path):
    out = tmp_path / "out"
    # No plots: their subject is the runs' results (test_demo checks that the demo draws them).
    cmd = ["demo", "--design", "ujoint", "--quick", "--lockstep", "--no-plots", "--out", str(out)]
    res = subprocess.run(
        [sys.executable, "-m", "cdcr_ctl", *cmd],
        capture_output=True,
        text=True,
        timeout=280,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert "| go_and_return | model |" in res.stdout
    (session,) = out.iterdir()
    rows = json.loads((session / "results.json").read_text())
    by = {r["compensation"]: r for r in rows}
    assert [r["experiment"] for r in rows] == ["go_and_return"] * 2 and set(by) == {"off", "model"}
    assert all(r["state"] == "completed" and r["samples"] > 500 for r in rows)
    # No attempt tripped (the demo keeps a tripped run's log and runs it again): neither the
    # velocity limit, the drives' following error nor the tracker divergence fired.
    runs = sorted((session / "runs").iterdir())
    assert len(runs) == 2, [p.name for p in runs]
    rig = load_rig_config(SIM_RIG)
    for run_dir in runs:
        run = load_run(run_dir)
        assert run.ended["outcome"] == "completed", run.ended["reason"]
        assert {"q_cmd", "q_act", "tip"} <= set(run.groups)
        assert not (run_dir / "plots").exists()  # --no-plots
        speed = np.abs(np.diff(run.q_cmd(), axis=0)) / np.diff(run.t_s)[:, None]
        assert speed.max() <= rig.limits.cable_velocity_mm_s
    # The tracker and the model share the tip frame: before the first run moves, the tracked tip
    # is where the model puts the straight arm's, up to the world's small pretension sag.
    first = load_run(runs[0])
    still = np.logical_and.accumulate((first.theta_cmd() == 0.0).all(axis=1))
    assert still[0]
    err = np.linalg.norm(first.tip() - tip_from_psi_for_run(first)(first.psi_cmd()), axis=1)
    assert err[still].max() < 5.0
    # Section 3's compensation, with the nominal model, takes out a good part of the error the
    # ideal geometric model leaves (dead zone, deformation and the world's other parameters).
    assert by["model"]["mean_mm"] < by["off"]["mean_mm"], (by["off"], by["model"])
