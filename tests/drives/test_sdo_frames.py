"""SDO configuration frames on the wire, byte by byte (CiA 301 expedited download)."""

from __future__ import annotations

import can
from drivesim import close_rig, drain, rig_config

from cdcr_ctl.drives.group import DriveGroup
from cdcr_ctl.sim.epos.rig import SimDriveBus


def test_configure_sends_expedited_sdo_downloads_and_nmt_start():
    cfg = rig_config(sync_period_s=0.002)
    sim = SimDriveBus(cfg, "virtual", cfg.can.channel).start()
    spy = can.Bus(interface="virtual", channel=cfg.can.channel)
    bus = can.Bus(interface="virtual", channel=cfg.can.channel, receive_own_messages=False)
    by = {d.cable: d for d in cfg.drives}
    group = DriveGroup(bus, cfg.can, [by[c.name] for c in cfg.robot.cables])
    try:
        group.boot()
        group.configure()
        frames = [(m.arbitration_id, bytes(m.data)) for m in drain(spy, 0.02, max_s=0.5)]
    finally:
        close_rig(cfg, sim, group, spy)
    # NMT reset communication of node 1 (COB-ID 0x000: command 0x82, node 1) and its boot-up.
    assert (0x000, bytes([0x82, 0x01])) in frames
    assert (0x701, b"\x00") in frames
    # 0x6060:00 = 8 (CSP): client command 0x2F (expedited, 1 byte), index LE, subindex, data.
    assert (0x601, bytes.fromhex("2f60600008000000")) in frames
    assert (0x581, bytes.fromhex("6060600000000000")) in frames  # server: download confirmed
    # 0x1017:00 = 50 ms producer heartbeat: command 0x2B (2 bytes).
    assert (0x602, bytes.fromhex("2b17100032000000")) in frames
    # 0x1016:01 = master 127, 300 ms: command 0x23 (4 bytes), 0x007F012C little endian.
    assert (0x603, bytes.fromhex("231610012c017f00")) in frames
    # RPDO1 mapping 0x1600:01 = 0x607A0020 (target position, 32 bit).
    assert (0x601, bytes.fromhex("2300160120007a60")) in frames
    # NMT start all nodes (0x01, 0) after configuration.
    assert (0x000, bytes([0x01, 0x00])) in frames
