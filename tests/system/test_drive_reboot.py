"""System: a drive that reboots mid-run quick-stops the rig; ``reset-fault`` reconfigures that
drive (its SDO set: PDO mapping, limits, heartbeats), says so, and ``enable`` works again. The
tripped run's run.yaml records the drive fault with the drive's own records (0x603F, 0x1003)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from faulthelp import call, make_ready, start_moving_run, start_sim_with_faults, status, wait_for
from syshelp import session, start_daemon, wait_for_socket

from cdcr_ctl.sim.faults import FaultClient

pytestmark = [pytest.mark.slow, pytest.mark.realtime, pytest.mark.timeout(240)]


def test_rebooted_drive_is_reconfigured_by_reset_fault_then_enables(tmp_path):
    with (
        session(tmp_path) as (work, rig, sim, _runs),
        start_sim_with_faults(sim, work / "faults.sock", tmp_path / "sim.log"),
        start_daemon(rig, tmp_path / "daemon.log") as d,
    ):
        fc = FaultClient(work / "faults.sock")
        wait_for_socket(work / "control.sock", d, tmp_path / "daemon.log")
        make_ready(work)
        res = start_moving_run(work, "reboot")
        fc.inject("drive_reboot", node=2)
        st = wait_for(lambda: (s := status(work))["fault"] and s, 10, "trip")
        assert st["fault"]["cause"] == "nmt:node2", st["fault"]
        assert "restarted" in st["fault"]["detail"]
        wait_for(lambda: status(work)["run"] is None, 10, "run end")
        # run.yaml records the drive fault with the drive's own records (read after it).
        run_yaml = Path(res["log_dir"]) / "run.yaml"
        doc = wait_for(
            lambda: (y := yaml.safe_load(run_yaml.read_text())).get("drive_fault") and y,
            10,
            "drive_fault in run.yaml",
        )
        assert doc["ended"]["outcome"] == "tripped"
        assert doc["drive_fault"]["cause"] == "nmt:node2"
        assert doc["drive_fault"]["diagnosis"].startswith("0x603F 0x0000")  # a fresh drive
        # The rebooted drive is PRE-OPERATIONAL with its factory PDO set: a plain fault reset
        # could not bring its feedback back. reset-fault reconfigures it first, and says so.
        out = wait_for(
            lambda: call(work, "reset_fault", confirm=True), 10, "fault reset", poll_s=0.3
        )
        lines = out["reconfigured"]
        assert len(lines) == 1 and lines[0].startswith("node 2: rebooted"), out
        assert "reconfigured" in lines[0]
        assert status(work)["fault"] is None
        call(work, "enable")
        wait_for(
            lambda: all(x["state"] == "OPERATION ENABLED" for x in status(work)["drives"]),
            10,
            "drives enabled after the reconfiguration",
        )
        # Its feedback flows again through the configured TPDO: still enabled a while on.
        wait_for(lambda: status(work)["fault"] is None, 2, "no new fault")
        assert all(x["state"] == "OPERATION ENABLED" for x in status(work)["drives"])
