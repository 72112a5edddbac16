"""SDO configuration frames on the wire, byte by byte (CiA 301 expedited download), for the rig
config the project ships (config/qi2023.yaml, on the virtual bus)."""

from __future__ import annotations

from drivesim import ROOT, drain, make_rig

from cdcr_ctl.config import load_rig_config


def test_configure_sends_expedited_sdo_downloads_and_nmt_start():
    rig = load_rig_config(ROOT / "config" / "qi2023.yaml")
    by = {d.cable: d for d in rig.drives}
    r = make_rig([by[c.name] for c in rig.robot.cables], start=False, sync_period_s=0.002)
    try:
        r.group.boot()
        r.group.configure()
        frames = [(m.arbitration_id, bytes(m.data)) for m in drain(r.spy, 0.02, max_s=0.5)]
    finally:
        r.close()
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
    # NMT start, node by node (a broadcast would also start nodes that are not ours), after
    # each node's configuration.
    starts = [i for i, f in enumerate(frames) if f[0] == 0x000 and f[1][0] == 0x01]
    assert [frames[i][1] for i in starts] == [bytes([0x01, n]) for n in (1, 2, 3)]
    last_sdo = max(i for i, f in enumerate(frames) if 0x601 <= f[0] <= 0x603)
    assert starts[0] > last_sdo
