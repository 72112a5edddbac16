"""System: `cdcr-ctl demo --lockstep` runs the simulated rig and the daemon end to end, on
simulated time (one process: the production daemon, drive layer, Modbus reader and NatNet parser
over the lock-step rig). The subject is the demo's results, not its timing: lock-step keeps this
test independent of the machine's load. The real-time processes path is exercised by
test_lockstep_vs_realtime, test_daemon_stops and test_fault_matrix."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cdcr_ctl.runlog import load_run, streams
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "interop"))
import nodejs  # tests/interop/nodejs.py: the viewers' own code on Node


@pytest.mark.slow
@pytest.mark.multicore
@pytest.mark.timeout(400)
def test_demo_runs_both_experiments_with_and_without_compensation(tmp_path):
    out = tmp_path / "out"
    res = subprocess.run(
        [sys.executable, "-m", "cdcr_ctl", "demo", "--quick", "--lockstep", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=380,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert "| planar_bend | model |" in res.stdout
    (session,) = out.iterdir()
    rows = json.loads((session / "results.json").read_text())
    by = {(r["experiment"], r["compensation"]): r for r in rows}
    assert set(by) == {(e, c) for e in ("planar_bend", "circle") for c in ("off", "model")}
    assert all(r["state"] == "completed" and r["samples"] > 100 for r in rows)
    for exp in ("planar_bend", "circle"):
        # Compensation with the nominal model already removes a good part of the tip error.
        assert by[(exp, "model")]["mean_mm"] < 0.8 * by[(exp, "off")]["mean_mm"]
    # A run that tripped (a busy machine can starve the simulator) is kept and run again: the
    # table reports the completed ones.
    runs = [session / "runs" / r["run"] for r in rows]
    for run_dir in runs:
        run = load_run(run_dir)
        assert run.ended["outcome"] == "completed"
        assert {"q_cmd", "q_act", "tension", "tip"} <= set(run.groups)
        assert (run_dir / "can.asc").stat().st_size > 0
        assert list((run_dir / "plots").glob("*.png"))
    # Every demo run's run.mcap in the official TypeScript readers (tests/interop): every
    # message, a message per logged row on each per-cycle channel.
    read = nodejs.read_mcap(*(run_dir / RUN_MCAP for run_dir in runs))
    for run_dir in runs:
        n = len(load_run(run_dir))
        got = read[str(run_dir / RUN_MCAP)]
        for reader in ("indexed", "stream"):
            res = got[reader]
            assert "error" not in res, (run_dir.name, reader, res["error"])
            assert {t: res["counts"][t] for t in streams.PER_CYCLE} == dict.fromkeys(
                streams.PER_CYCLE, n
            ), (run_dir.name, reader)
            assert res["failures"] == {"json": 0, "missingHead": {}}, (run_dir.name, reader)
        assert got["indexed"]["statisticsCount"] == sum(got["indexed"]["counts"].values())
