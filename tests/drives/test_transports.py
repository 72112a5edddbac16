"""The same driver code over an slcan pty to simulated drives in another process; socketcan; and
canopen's own unmodified BaseNode402 against the simulated node (plain CiA 301/402)."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import canopen
import pytest
from drivesim import Cycler, rig_config, wait_until

from cdcr_ctl.drives.canbus import open_bus, socketcan_available
from cdcr_ctl.drives.cia402 import State
from cdcr_ctl.drives.group import DriveGroup
from cdcr_ctl.sim.epos.rig import SimDriveBus

ROOT = Path(__file__).resolve().parents[2]


def test_driver_runs_unchanged_over_slcan_against_another_process(tmp_path):
    link = tmp_path / "can"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "cdcr_ctl.sim.epos",
            str(ROOT / "config" / "qi2023.yaml"),
            "--link",
            str(link),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout.readline().strip() == str(link)
        cfg = rig_config(sync_period_s=0.005, feedback_timeout_s=0.25)
        cfg = cfg.model_copy(
            update={"can": cfg.can.model_copy(update={"interface": "slcan", "channel": str(link)})}
        )
        by = {d.cable: d for d in cfg.drives}
        with DriveGroup(open_bus(cfg.can), cfg.can, [by[c.name] for c in cfg.robot.cables]) as g:
            g.boot()
            g.configure()
            assert g.read_identity(2)["vendor_id"] == 0xFB  # maxon
            with Cycler(g, 0.005) as cyc:
                g.enable()
                cyc.targets = [2000, -1000, -1000]
                assert wait_until(
                    lambda: [f.position_counts for f in g.feedback()] == [2000, -1000, -1000]
                )
            assert g.first_fault() is None
    finally:
        proc.terminate()
        proc.wait(10)


def test_socketcan_path(tmp_path):
    ok, why = socketcan_available("can0")
    if not ok:
        pytest.skip(f"SocketCAN not usable here: {why}")
    cfg = rig_config()
    cfg = cfg.model_copy(
        update={"can": cfg.can.model_copy(update={"interface": "socketcan", "channel": "can0"})}
    )
    bus = open_bus(cfg.can)
    assert bus.channel_info
    bus.shutdown()


def test_stock_canopen_basenode402_drives_the_simulated_node():
    cfg = rig_config()
    sim = SimDriveBus(cfg, "virtual", cfg.can.channel).start()
    net = canopen.Network(can.Bus(interface="virtual", channel=cfg.can.channel))
    net.connect()
    stop = threading.Event()

    def syncs():
        while not stop.is_set():
            net.sync.transmit()
            time.sleep(0.002)

    try:
        from cdcr_ctl.sim.epos.od import build_od

        node = canopen.BaseNode402(1, build_od(1, "epos4"))
        net.add_node(node)
        node.nmt.state = "RESET COMMUNICATION"
        node.nmt.wait_for_bootup(5)
        assert node.sdo[0x1000].raw == 0x00020192
        assert node.sdo[0x1018][1].raw == 0xFB
        node.setup_402_state_machine(read_pdos=True)
        node.nmt.state = "OPERATIONAL"
        t = threading.Thread(target=syncs, daemon=True)
        t.start()
        node.sdo[0x6060].raw = 8
        node.state = "OPERATION ENABLED"
        assert node.state == "OPERATION ENABLED"
        assert sim.node(1).state is State.OPERATION_ENABLED
        assert isinstance(node.sdo[0x6064].raw, int)
    finally:
        stop.set()
        net.disconnect()
        sim.stop()
