"""The same driver code over slcan on a pty, against simulated drives in another process
(``python -m cdcr_ctl.sim.epos``), including faults injected there; socketcan where the kernel
has it; errors that name the transport."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from drivesim import ROOT, Cycler, wait_until

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.drives import CanBusConfig
from cdcr_ctl.drives.canbus import open_bus, socketcan_available
from cdcr_ctl.drives.cia402 import State
from cdcr_ctl.drives.group import DriveGroup
from cdcr_ctl.errors import CommError


class SimProcess:
    """``python -m cdcr_ctl.sim.epos ...`` with its stdin command channel."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cdcr_ctl.sim.epos", *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        assert self.proc.stdout is not None
        self.path = self.proc.stdout.readline().strip()

    def ask(self, line: str) -> str:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.proc.stdout.readline().strip()

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)
        for pipe in (self.proc.stdin, self.proc.stdout):
            if pipe is not None:
                pipe.close()


def slcan_cfg(path: str | Path) -> CanBusConfig:
    return CanBusConfig(
        interface="slcan", channel=str(path), sync_period_s=0.005, feedback_timeout_s=0.25
    )


def test_driver_runs_unchanged_over_slcan_against_another_process(tmp_path):
    link = tmp_path / "can"
    sim = SimProcess(str(ROOT / "config" / "qi2023.yaml"), "--link", str(link))
    try:
        assert sim.path == str(link)
        rig = load_rig_config(ROOT / "config" / "qi2023.yaml")
        by = {d.cable: d for d in rig.drives}
        drives = [by[c.name] for c in rig.robot.cables]
        cfg = slcan_cfg(link)
        with DriveGroup(open_bus(cfg), cfg, drives) as g:
            g.boot()
            g.configure()
            assert g.read_identity(2)["vendor_id"] == 0xFB  # maxon
            with Cycler(g) as cyc:
                g.enable()
                cyc.targets = [2000, -1000, -1000]
                assert wait_until(
                    lambda: [f.position_counts for f in g.feedback()] == [2000, -1000, -1000]
                )
                assert sim.ask("positions") == "ok 2000 -1000 -1000"
                assert g.first_fault() is None
                assert sim.ask("fault 2 0x8611") == "ok fault 2"  # injected in the other process
                assert wait_until(lambda: g.fault() is not None)
                assert wait_until(lambda: g.quick_stop_at_sync is not None)
            f = g.fault()
            assert (f.cause, f.node, f.code) == ("emcy:node2:0x8611", 2, 0x8611)
            assert g.quick_stop_at_sync - g.fault_at_sync <= 2
            assert wait_until(lambda: "OPERATION_ENABLED" not in sim.ask("states"))
            assert sim.ask("states").split()[2] == "FAULT"
    finally:
        sim.close()


def test_adapter_unplugged_the_master_latches_a_bus_fault_and_the_drives_stop(tmp_path):
    link = tmp_path / "can"
    sim = SimProcess("--node", "1", "--node", "2:epos2", "--link", str(link))
    try:
        from drivesim import drive_cfgs

        drives = [*drive_cfgs(1), drive_cfgs(2, "epos2", "pp")[1]]
        cfg = slcan_cfg(link)
        with DriveGroup(open_bus(cfg), cfg, drives) as g:
            g.boot()
            g.configure()
            with Cycler(g):
                g.enable()
                assert sim.ask("unplug") == "ok unplugged"
                assert wait_until(lambda: g.fault() is not None)
            f = g.fault()
            assert f.node == 0 and f.cause in ("bus:rx", "bus:send", "no_feedback:all")
            assert f"CAN slcan:{link}" in f.text
            # the drives no longer hear the master: their heartbeat consumers stop them
            assert wait_until(lambda: sim.ask("states") == "ok FAULT FAULT")
    finally:
        sim.close()


def test_socketcan_path():
    ok, why = socketcan_available("can0")
    if not ok:
        pytest.skip(f"SocketCAN not usable here: {why}")
    bus = open_bus(CanBusConfig(interface="socketcan", channel="can0"))
    try:
        assert bus.channel_info
    finally:
        bus.shutdown()


def test_open_errors_name_interface_and_channel(tmp_path):
    missing = tmp_path / "no-such-adapter"
    with pytest.raises(CommError, match=f"CAN slcan:{missing}: cannot open"):
        open_bus(CanBusConfig(interface="slcan", channel=str(missing)))
    with pytest.raises(CommError, match="CAN no-such-interface:x: cannot open"):
        open_bus(CanBusConfig(interface="no-such-interface", channel="x"))


def test_sim_cli_answers_bad_commands():
    from cdcr_ctl.sim.epos.__main__ import command
    from cdcr_ctl.sim.epos.rig import SimDriveBus

    drives = SimDriveBus([(1, "epos4")], "virtual", "cli-test")
    try:
        assert command(drives, "fault 9 0x8611").startswith("error fault")
        assert command(drives, "fault 1 nonsense").startswith("error fault")
        assert command(drives, "dance 1").startswith("error unknown command")
        assert command(drives, "fault 1 0x2310") == "ok fault 1"
        assert drives.node(1).state is State.FAULT
    finally:
        drives.stop()
