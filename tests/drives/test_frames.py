"""The drive protocol on the wire, byte by byte, against simulated EPOS4 nodes: NMT boot, the SDO
configuration transcript, the controlword walk 0x06, 0x07, 0x0F, and the PDOs around each SYNC."""

from __future__ import annotations

import struct

import pytest
from drivesim import (
    Cycler,
    collect,
    drain,
    drive_cfgs,
    frames_of,
    is_heartbeat,
    make_rig,
    wait_until,
)

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import State, state_of
from cdcr_ctl.errors import DriveFault

#: CiA 301 expedited download command byte by data size (size indicated).
EXPEDITED = {1: 0x2F, 2: 0x2B, 4: 0x23}


def sdo_download(index: int, sub: int, data: bytes) -> bytes:
    return bytes([EXPEDITED[len(data)]]) + struct.pack("<HB", index, sub) + data.ljust(4, b"\0")


def sdo_upload(index: int, sub: int) -> bytes:
    return bytes([0x40]) + struct.pack("<HB", index, sub) + bytes(4)


def test_boot_and_sdo_configuration_transcript():
    r = make_rig(drive_cfgs(1), start=False)
    try:
        r.group.boot()
        boot = drain(r.spy)
        assert [(m.arbitration_id, bytes(m.data)) for m in boot[:2]] == [
            (0x000, bytes([0x82, 0x01])),  # NMT reset communication, node 1
            (0x701, bytes([0x00])),  # boot-up
        ]
        r.group.configure()
        msgs = drain(r.spy)
    finally:
        r.close()
    requests = frames_of(msgs, 0x601)
    responses = frames_of(msgs, 0x581)
    d = r.drives[0]
    expected = [sdo_upload(0x1018, 1)]
    expected += [sdo_download(w.index, w.sub, w.data) for w in epos.configuration_writes(d, r.cfg)]
    expected += [sdo_upload(0x60C2, 2)]
    assert requests == expected
    assert responses[0] == bytes.fromhex("43 18 10 01 fb 00 00 00")  # maxon vendor id 0xFB
    # every download confirmed with "download response" 0x60 + index + subindex
    assert responses[1:-1] == [bytes([0x60]) + r_[1:4] + bytes(4) for r_ in requests[1:-1]]
    assert responses[-1] == bytes.fromhex("4f c2 60 02 fd 00 00 00")  # index -3: milliseconds
    nmt = [bytes(m.data) for m in msgs if m.arbitration_id == 0x000]
    assert nmt == [bytes([0x01, 0x01])]  # NMT start node 1, after the configuration


def test_enable_walks_06_07_0f_and_statusword_confirms_each_step(rig):
    drain(rig.spy)
    with Cycler(rig.group):
        rig.group.enable()
        assert [f.state for f in rig.group.feedback()] == [State.OPERATION_ENABLED] * 3
        msgs = drain(rig.spy, 0.02, max_s=0.2)
    for node in (1, 2, 3):
        assert frames_of(msgs, 0x300 + node) == [b"\x06\x00", b"\x07\x00", b"\x0f\x00"]
    states = [state_of(struct.unpack_from("<H", data)[0]) for data in frames_of(msgs, 0x181)]
    seen = [s for i, s in enumerate(states) if i == 0 or s is not states[i - 1]]
    assert seen[-4:] == [
        State.SWITCH_ON_DISABLED,
        State.READY_TO_SWITCH_ON,
        State.SWITCHED_ON,
        State.OPERATION_ENABLED,
    ]


def test_cycle_is_rpdos_then_sync_then_tpdos(rig):
    g = rig.group
    with Cycler(g) as cyc:
        g.enable()
        cyc.targets = [1000, -500, 7]
        assert wait_until(lambda: [f.position_counts for f in g.feedback()] == [1000, -500, 7])
        drain(rig.spy, max_s=0.05)
        msgs = collect(rig.spy, 0.05)
    ids = [m.arbitration_id for m in msgs]
    i = next(k for k, c in enumerate(ids) if c == 0x080 and k >= 3)
    assert ids[i - 3 : i] == [0x201, 0x202, 0x203]
    assert [bytes(m.data) for m in msgs[i - 3 : i]] == [
        struct.pack("<i", 1000),
        struct.pack("<i", -500),
        struct.pack("<i", 7),
    ]
    assert msgs[i].dlc == 0  # SYNC carries no data
    # the TPDOs answering this SYNC (the next cycle's RPDOs may pass them on a loaded machine)
    tpdos = [m for m in msgs[i + 1 :] if 0x181 <= m.arbitration_id <= 0x183][:3]
    after = {m.arbitration_id: bytes(m.data) for m in tpdos}
    # statusword 0x1637: OPERATION ENABLED (0x37 with voltage), remote (bit 9), target reached
    # (bit 10), drive follows the command value (bit 12); then the actual position.
    assert after == {
        0x181: bytes.fromhex("3716") + struct.pack("<i", 1000),
        0x182: bytes.fromhex("3716") + struct.pack("<i", -500),
        0x183: bytes.fromhex("3716") + struct.pack("<i", 7),
    }
    # the factory TPDO2 (0x280 + id) was switched off by the configuration
    assert not [m for m in msgs if 0x281 <= m.arbitration_id <= 0x283]
    assert rig.sim.actual_positions() == [1000, -500, 7]


def test_build_cycle_is_pure(rig):
    drain(rig.spy)
    before = rig.group.sync_count
    frames = [rig.group.build_cycle([5, 6, 7]) for _ in range(3)]
    assert (
        frames[0]
        == frames[1]
        == frames[2]
        == [
            (0x201, bytes.fromhex("05000000")),
            (0x202, bytes.fromhex("06000000")),
            (0x203, bytes.fromhex("07000000")),
            (0x080, b""),
        ]
    )
    assert rig.group.sync_count == before
    assert [m for m in collect(rig.spy, 0.05) if not is_heartbeat(m)] == []


def test_sdo_refusal_names_node_object_and_abort_code():
    """Config says EPOS4 in CSP, the device is an EPOS2: it refuses mode 8 (value range)."""
    from cdcr_ctl.sim.epos.rig import SimDriveBus

    r = make_rig(drive_cfgs(1), start=False)
    try:
        r.sim.stop()
        ch = r.cfg.channel
        r.sim = SimDriveBus([(1, "epos2")], "virtual", ch).start()
        r.group.boot()
        with pytest.raises(DriveFault) as exc:
            r.group.configure()
    finally:
        r.close()
    assert exc.value.node == 1 and exc.value.code == 0x06090030
    assert "0x6060:00 (modes of operation) refused" in str(exc.value)


def test_send_cycle_sends_exactly_what_build_cycle_builds(rig):
    """The cyclic short path (every drive csp/pm) and the pure builder agree byte for byte."""
    g = rig.group
    drain(rig.spy)
    for targets in ([5, 6, 7], [-2_000_000_000, 0, 2_000_000_000]):
        want = g.build_cycle(targets)
        g.send_cycle(targets)
        # Only the master's frames: the drives' TPDOs answering this SYNC (or, on a loaded
        # machine, a late answer to the previous one) share the bus with them.
        ours = {cob_id for cob_id, _ in want}
        sent = [m for m in collect(rig.spy, 0.05) if m.arbitration_id in ours][: len(want)]
        assert [(m.arbitration_id, bytes(m.data)) for m in sent] == want
    with pytest.raises(ValueError):
        g.send_cycle([1, 2])  # one target per drive
