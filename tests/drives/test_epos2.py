"""EPOS2: profile position and interpolated position (PVT records through 0x20C1), no CSP."""

from __future__ import annotations

import itertools

import can
import pytest
from drivesim import Cycler, rig_config, wait_until

from cdcr_ctl.drives.cia402 import State
from cdcr_ctl.drives.group import DriveGroup, parse_pvt_payload, pvt_payload
from cdcr_ctl.sim.epos.rig import SimDriveBus

_n = itertools.count()


def epos2_rig(mode: str):
    cfg = rig_config(sync_period_s=0.005)
    drives = [d.model_copy(update={"type": "epos2", "mode": mode}) for d in cfg.drives]
    cfg = cfg.model_copy(update={"drives": drives})
    sim = SimDriveBus(cfg, "virtual", cfg.can.channel).start()
    bus = can.Bus(interface="virtual", channel=cfg.can.channel, receive_own_messages=False)
    by = {d.cable: d for d in cfg.drives}
    group = DriveGroup(bus, cfg.can, [by[c.name] for c in cfg.robot.cables])
    group.boot()
    group.configure()
    return cfg, sim, group


def test_pvt_record_layout():
    data = pvt_payload(-1000, -300, 5)
    assert data == bytes.fromhex("18fcffffd4feff05")
    assert parse_pvt_payload(data) == (-1000, -300, 5)


@pytest.mark.parametrize("mode", ["pp", "ip"])
def test_epos2_follows_targets(mode):
    _cfg, sim, group = epos2_rig(mode)
    try:
        assert all(n.kind == "epos2" for n in sim.nodes)
        with Cycler(group, 0.005) as cyc:
            group.enable()
            assert all(f.state is State.OPERATION_ENABLED for f in group.feedback())
            for k in range(1, 41):
                cyc.targets = [100 * k, -50 * k, -50 * k]
                wait_until(lambda: False, 0.01)
            assert wait_until(
                lambda: [f.position_counts for f in group.feedback()] == [4000, -2000, -2000], 5
            )
        assert group.first_fault() is None
        if mode == "ip":
            assert sim.nodes[0].mode == 7
    finally:
        group.close()
        sim.stop()


def test_epos2_refuses_csp():
    from canopen.sdo.exceptions import SdoAbortedError

    _cfg, sim, group = epos2_rig("pp")
    try:
        with pytest.raises(SdoAbortedError):
            group._drives[0].node.sdo.download(0x6060, 0, b"\x08")
    finally:
        group.close()
        sim.stop()
