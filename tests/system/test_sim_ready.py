"""The simulated rig's ready line says where and how to connect (the load cells' serial
settings, the tracker's bound ports), and a second simulator of the same rig refuses before it
replaces a link or binds a port of the first."""

from __future__ import annotations

import os

import pytest
from syshelp import session

from cdcr_ctl.ownership import AlreadyOwned
from cdcr_ctl.sim.rig import SimRig
from cdcr_ctl.sim.simconfig import load_sim_config

pytestmark = [pytest.mark.realtime, pytest.mark.timeout(120)]


def test_ready_line_has_serial_settings_and_ports_and_a_second_sim_refuses(tmp_path):
    with session(tmp_path, tcp_links=False) as (work, _rig, sim, _runs):
        loaded = load_sim_config(sim)
        with SimRig(loaded) as first:
            info = first.connection_info()
            serial = loaded.rig.sensors.load_cells.serial
            assert os.path.realpath(serial.port) == info["load_cells"]["port"]  # the pty
            assert info["load_cells"] == {
                "port": info["load_cells"]["port"],
                "baudrate": serial.baudrate,
                "parity": serial.parity,
                "stopbits": serial.stopbits,
            }
            tracker = loaded.rig.sensors.tracker
            assert info["tracker"]["kind"] == "natnet"
            assert info["tracker"]["host"] == tracker.host
            assert info["tracker"]["command_port"] == tracker.command_port
            assert isinstance(info["tracker"]["data_port"], int) and info["tracker"]["data_port"]
            links = {p: os.readlink(work / p) for p in ("can", "loadcells")}

            with pytest.raises(AlreadyOwned, match=rf"already running \(pid {os.getpid()};"):
                SimRig(load_sim_config(sim)).start()
            assert {p: os.readlink(work / p) for p in links} == links
            assert first.connection_info() == info
