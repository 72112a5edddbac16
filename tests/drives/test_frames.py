"""Drive protocol checked byte by byte: SDO configuration, 402 controlwords, PDOs after SYNC."""

from __future__ import annotations

import struct

import pytest
from drivesim import Cycler, drain, rig_config, wait_until

from cdcr_ctl.drives.busload import check_bus_load, cycle_load, frame_bits, pdo_cycle_frames
from cdcr_ctl.drives.cia402 import State, next_controlword, state_of
from cdcr_ctl.drives.emcy import decode_emcy
from cdcr_ctl.drives.group import (
    configuration_writes,
    parse_tpdo_feedback,
    pdo_mapping_writes,
    rpdo_controlword_payload,
    rpdo_target_payload,
)
from cdcr_ctl.errors import ConfigError


def test_payload_builders_are_little_endian_cia_types():
    assert rpdo_target_payload(-2) == bytes.fromhex("feffffff")
    assert rpdo_target_payload(0x12345678) == bytes.fromhex("78563412")
    assert rpdo_controlword_payload(0x000F) == bytes.fromhex("0f00")
    assert parse_tpdo_feedback(bytes.fromhex("3706feffffff")) == (0x0637, -2)
    assert parse_tpdo_feedback(b"\x00" * 5) is None


def test_pdo_mapping_follows_cia301_disable_map_enable():
    w = pdo_mapping_writes(3)
    # RPDO1: disable COB-ID 0x203, clear count, map 0x607A:00 32 bit, count 1, sync, enable.
    assert w[:6] == [
        (0x1400, 1, struct.pack("<I", 0x8000_0203)),
        (0x1600, 0, b"\x00"),
        (0x1600, 1, struct.pack("<I", 0x607A_0020)),
        (0x1600, 0, b"\x01"),
        (0x1400, 2, b"\x01"),
        (0x1400, 1, struct.pack("<I", 0x203)),
    ]
    tpdo = [x for x in w if x[0] in (0x1800, 0x1A00)]
    assert (0x1A00, 1, struct.pack("<I", 0x6041_0010)) in tpdo
    assert (0x1A00, 2, struct.pack("<I", 0x6064_0020)) in tpdo
    assert tpdo[-1] == (0x1800, 1, struct.pack("<I", 0x183))


def test_configuration_writes_from_yaml():
    cfg = rig_config(sync_period_s=0.002)
    d = cfg.drives[0]
    w = {(i, s): v for i, s, v in configuration_writes(d, cfg.can)}
    assert w[(0x6060, 0)] == b"\x08"  # CSP
    assert w[(0x60C2, 1)] == b"\x02" and w[(0x60C2, 2)] == struct.pack("<b", -3)  # 2 ms
    assert w[(0x6065, 0)] == struct.pack("<I", d.following_error_window_counts)
    assert w[(0x607D, 1)] == struct.pack("<i", d.software_limits_counts[0])
    assert w[(0x1017, 0)] == struct.pack("<H", d.heartbeat_producer_ms)
    assert w[(0x1016, 1)] == struct.pack("<I", (127 << 16) | d.heartbeat_consumer_ms)


def test_statusword_decoding_and_state_walk():
    assert state_of(0x0240) is State.SWITCH_ON_DISABLED
    assert state_of(0x0221) is State.READY_TO_SWITCH_ON
    assert state_of(0x0233) is State.SWITCHED_ON
    assert state_of(0x0637) is State.OPERATION_ENABLED
    assert state_of(0x0217) is State.QUICK_STOP_ACTIVE
    assert state_of(0x0208) is State.FAULT
    walk, s = [], State.SWITCH_ON_DISABLED
    order = [State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.OPERATION_ENABLED]
    for nxt in order:
        walk.append(next_controlword(s, State.OPERATION_ENABLED))
        s = nxt
    assert walk == [0x06, 0x07, 0x0F]
    assert next_controlword(State.FAULT, State.OPERATION_ENABLED) == 0x80


def test_emcy_decoding():
    e = decode_emcy(2, bytes.fromhex("1186010000000000"))
    assert (e.node, e.code, e.register, e.text) == (2, 0x8611, 1, "following error")
    assert decode_emcy(2, b"\x00") is None
    assert "current" in decode_emcy(1, bytes.fromhex("1023010000000000")).text


def test_bus_load_135_bits_and_70_percent_limit():
    assert frame_bits(8) == 135 and frame_bits(0) == 55
    load = cycle_load(pdo_cycle_frames(3), 0.001, 1_000_000)
    assert load.bits_per_cycle == 55 + 3 * 95 + 3 * 115 and load.load < 0.70
    with pytest.raises(ConfigError, match="over the 70 %"):
        check_bus_load(4, 0.001, 1_000_000, 0.70, "rig.yaml")


def test_enable_sends_06_07_0f_and_pdos_follow_sync(rig):
    _cfg, sim, group, spy = rig
    drain(spy)
    with Cycler(group, 0.002) as cyc:
        group.enable()
        assert [f.state for f in group.feedback()] == [State.OPERATION_ENABLED] * 3
        frames = drain(spy, 0.02, max_s=0.05)
        cws = [m.data[0] for m in frames if m.arbitration_id == 0x301]
        assert cws == [0x06, 0x07, 0x0F]
        cyc.targets = [1000, -500, -500]
        assert wait_until(
            lambda: [f.position_counts for f in group.feedback()] == [1000, -500, -500]
        )
        drain(spy, max_s=0.05)
        frames = drain(spy, 0.01, max_s=0.03)
    # Every cycle: RPDO1 of nodes 1..3 with the target, then SYNC, then each node's TPDO1.
    ids = [m.arbitration_id for m in frames]
    i = next(k for k, c in enumerate(ids) if c == 0x080 and k >= 3)
    assert ids[i - 3 : i] == [0x201, 0x202, 0x203]
    assert frames[i - 3].data == struct.pack("<i", 1000)
    after = frames[i + 1 : i + 4]
    assert sorted(m.arbitration_id for m in after) == [0x181, 0x182, 0x183]
    tp = {m.arbitration_id: parse_tpdo_feedback(bytes(m.data)) for m in after}
    assert tp[0x181][1] == 1000 and state_of(tp[0x181][0]) is State.OPERATION_ENABLED
    assert sim.actual_positions() == [1000, -500, -500]
