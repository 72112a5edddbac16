"""Pure protocol pieces: CiA 402 decoding against canopen's own table, payload packers, the EMCY
table, bus load arithmetic, SDO configuration lists and the config rules per drive family."""

from __future__ import annotations

import struct

import pytest
from canopen.profiles.p402 import State402
from drivesim import bus_cfg, drive_cfgs
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from cdcr_ctl.config.drives import DriveConfig
from cdcr_ctl.drives import epos
from cdcr_ctl.drives.busload import (
    check_bus_load,
    check_drives_bus_load,
    cycle_load,
    drive_cycle_frames,
    frame_bits,
    pdo_cycle_frames,
)
from cdcr_ctl.drives.canbus import bus_kwargs
from cdcr_ctl.drives.cia402 import (
    STATE_BITS,
    State,
    next_controlword,
    state_of,
)
from cdcr_ctl.drives.emcy import EPOS_ERROR_TABLE, decode_emcy, emcy_text, encode_emcy
from cdcr_ctl.drives.heartbeat import HeartbeatConsumer
from cdcr_ctl.errors import ConfigError

# ------------------------------------------------------------------------------- CiA 402


@given(st.integers(0, 0xFFFF))
def test_state_of_agrees_with_canopens_statusword_table(sw):
    """Our Enum decoding and canopen's BaseNode402 string table name the same state."""
    theirs = next(
        (name for name, (mask, value) in State402.SW_MASK.items() if sw & mask == value),
        "UNKNOWN",
    )
    assert state_of(sw).value == theirs


def test_state_bits_round_trip():
    for state, bits in STATE_BITS.items():
        assert state_of(bits | 0x0200) is state


def walk(start: State, target: State) -> list[int]:
    """Controlwords next_controlword gives, applying CiA 402 transitions by hand."""
    after = {
        (State.SWITCH_ON_DISABLED, 0x06): State.READY_TO_SWITCH_ON,
        (State.READY_TO_SWITCH_ON, 0x07): State.SWITCHED_ON,
        (State.SWITCHED_ON, 0x0F): State.OPERATION_ENABLED,
        (State.OPERATION_ENABLED, 0x07): State.SWITCHED_ON,
        (State.SWITCHED_ON, 0x06): State.READY_TO_SWITCH_ON,
        (State.OPERATION_ENABLED, 0x06): State.READY_TO_SWITCH_ON,
        (State.QUICK_STOP_ACTIVE, 0x00): State.SWITCH_ON_DISABLED,
        (State.FAULT, 0x80): State.SWITCH_ON_DISABLED,
    }
    out, s = [], start
    for _ in range(6):
        cw = next_controlword(s, target)
        if cw is None:
            break
        out.append(cw)
        s = after.get((s, cw), State.SWITCH_ON_DISABLED if cw == 0 else s)
    assert s is target
    return out


def test_controlword_walks():
    assert walk(State.SWITCH_ON_DISABLED, State.OPERATION_ENABLED) == [0x06, 0x07, 0x0F]
    assert walk(State.FAULT, State.OPERATION_ENABLED) == [0x80, 0x06, 0x07, 0x0F]
    assert walk(State.QUICK_STOP_ACTIVE, State.OPERATION_ENABLED) == [0x00, 0x06, 0x07, 0x0F]
    assert walk(State.OPERATION_ENABLED, State.READY_TO_SWITCH_ON) == [0x06]
    assert walk(State.OPERATION_ENABLED, State.SWITCH_ON_DISABLED) == [0x00]
    assert next_controlword(State.NOT_READY_TO_SWITCH_ON, State.OPERATION_ENABLED) is None


# ------------------------------------------------------------------------------- payloads


@given(st.integers(-(2**31), 2**31 - 1))
def test_target_payload_is_int32_le(t):
    assert epos.target_payload(t) == struct.pack("<i", t)
    assert epos.parse_tpdo_feedback(struct.pack("<H", 0x1237) + epos.target_payload(t)) == (
        0x1237,
        t,
    )


@given(st.integers(-(2**31), 2**31 - 1), st.integers(-(2**23), 2**23 - 1), st.integers(0, 255))
def test_pvt_record_round_trip(p, v, t):
    data = epos.pvt_payload(p, v, t)
    assert len(data) == 8 and epos.parse_pvt(data) == (p, v, t)


def test_pvt_record_bytes_and_range():
    # position -1000, velocity -300 rpm, 5 ms: int32 LE, int24 LE, uint8
    assert epos.pvt_payload(-1000, -300, 5) == bytes.fromhex("18fcffff d4feff 05")
    with pytest.raises(ValueError, match="24 bits"):
        epos.pvt_payload(0, 2**23, 1)
    with pytest.raises(ValueError, match="8 bits"):
        epos.pvt_payload(0, 0, 256)
    assert epos.parse_pvt(b"\x00" * 7) is None


def test_pp_and_controlword_payloads():
    assert epos.pp_setpoint_payload(-2, 0x3F) == bytes.fromhex("feffffff 3f00")
    assert epos.controlword_payload(0x010F) == bytes.fromhex("0f01")
    assert epos.parse_tpdo_feedback(b"\x00" * 5) is None
    assert epos.counts_per_s_to_rpm(2048.0, 2048) == 60


# ------------------------------------------------------------------------------- EMCY


def test_emcy_codes_the_issue_names():
    for code, text in [
        (0x8611, "following error"),
        (0x8130, "heartbeat"),
        (0x81FD, "bus off"),
        (0x3210, "over-voltage"),
        (0x2310, "over-current"),
        (0x8A80, "negative limit switch"),
        (0x8A81, "positive limit switch"),
    ]:
        assert text in emcy_text(code, "epos4")
    # The device-specific range differs between generations: one table, a column per family.
    assert emcy_text(0xFF06, "epos2") == "negative limit switch error"
    assert "interpolated position" in emcy_text(0xFF0C, "epos2")
    assert emcy_text(0x5F00, "epos4") == "unknown error (device hardware error)"


def test_emcy_table_has_no_duplicate_per_family():
    seen = set()
    for code, fam, _ in EPOS_ERROR_TABLE:
        for f in ("epos4", "epos2") if fam == "both" else (fam,):
            assert (code, f) not in seen
            seen.add((code, f))


@given(st.integers(0, 0xFFFF), st.binary(min_size=0, max_size=5))
def test_emcy_encode_decode(code, extra):
    e = decode_emcy(7, encode_emcy(code, data=extra))
    assert (e.node, e.code) == (7, code)
    assert e.data == extra.ljust(5, b"\0")
    assert e.register & 0x01 == (1 if code else 0)
    assert f"0x{code:04X}" in str(e)


@given(st.binary(max_size=2))
def test_emcy_short_frames_are_rejected(data):
    assert decode_emcy(1, data) is None


def test_emcy_bytes():
    e = decode_emcy(2, bytes.fromhex("1186110000000000"))
    assert (e.code, e.register, e.text) == (0x8611, 0x11, "following error")


# ------------------------------------------------------------------------------- bus load


def test_frame_bits_with_worst_case_stuffing():
    assert frame_bits(8) == 135 and frame_bits(0) == 55
    assert frame_bits(4) == 44 + 32 + (34 + 32 - 1) // 4 + 3
    with pytest.raises(ValueError):
        frame_bits(9)


def test_three_csp_drives_fit_1khz_at_1mbit_four_do_not():
    load = cycle_load(pdo_cycle_frames(3), 0.001, 1_000_000)
    assert load.bits_per_cycle == 55 + 3 * 95 + 3 * 115 == 685
    assert load.load == pytest.approx(0.685)
    assert check_bus_load(3, 0.001, 1_000_000, 0.70).load < 0.70
    with pytest.raises(ConfigError, match="over the 70 %") as exc:
        check_bus_load(4, 0.001, 1_000_000, 0.70, "rig.yaml")
    assert exc.value.key == "can.sync_period_s" and exc.value.file == "rig.yaml"


def test_bus_load_follows_the_modes():
    ip = drive_cfgs(3, "epos2", "ip")
    assert drive_cycle_frames(ip) == [0, 8, 8, 8, 6, 6, 6]
    assert drive_cycle_frames(drive_cfgs(2, "epos4", "pp")) == [0, 6, 6, 6, 6]
    with pytest.raises(ConfigError):
        check_drives_bus_load(ip, 0.001, 1_000_000, 0.70)
    assert check_drives_bus_load(ip, 0.002, 1_000_000, 0.70).load < 0.5


# ------------------------------------------------------------------------------- SDO lists


def test_pdo_mapping_follows_cia301_disable_map_enable():
    w = [(x.index, x.sub, x.data) for x in epos.pdo_mapping_writes(3)]
    assert w[:6] == [
        (0x1400, 1, struct.pack("<I", 0x8000_0203)),
        (0x1600, 0, b"\x00"),
        (0x1600, 1, struct.pack("<I", 0x607A_0020)),
        (0x1600, 0, b"\x01"),
        (0x1400, 2, b"\x01"),  # synchronous: applied at the next SYNC
        (0x1400, 1, struct.pack("<I", 0x203)),
    ]
    assert (0x1A00, 1, struct.pack("<I", 0x6041_0010)) in w
    assert (0x1A00, 2, struct.pack("<I", 0x6064_0020)) in w
    # every factory PDO we do not use is switched off
    for comm, cob in [(0x1402, 0x403), (0x1403, 0x503), (0x1801, 0x283), (0x1802, 0x383)]:
        assert (comm, 1, struct.pack("<I", 0x8000_0000 | cob)) in w


def test_pdo_layouts_per_mode():
    from cdcr_ctl.drives.cia402 import Mode

    pp = epos.pdo_layout(1, Mode.PROFILE_POSITION)
    assert pp.setpoint.entries == (0x607A_0020, 0x6040_0010) and pp.setpoint.transmission == 255
    ip = epos.pdo_layout(1, Mode.INTERPOLATED_POSITION)
    assert ip.setpoint.entries == (0x20C1_0040,) and ip.setpoint.n_bytes == 8
    pm = epos.pdo_layout(1, Mode.POSITION_MODE)
    assert pm.setpoint.entries == (0x2062_0020,) and pm.setpoint_is_sync


def test_configuration_writes_from_config():
    d = drive_cfgs(1, following_error_timeout_ms=25, quick_stop_option_code=6)[0]
    cfg = bus_cfg("x", sync_period_s=0.002)
    w = {(x.index, x.sub): x.data for x in epos.configuration_writes(d, cfg)}
    assert w[(0x6060, 0)] == b"\x08"  # CSP
    assert w[(0x60C2, 1)] == b"\x02"  # 2 ms interpolation period = SYNC period
    assert w[(0x6065, 0)] == struct.pack("<I", d.following_error_window_counts)
    assert w[(0x6066, 0)] == struct.pack("<H", 25)
    assert w[(0x605A, 0)] == struct.pack("<h", 6)
    assert w[(0x607D, 1)] == struct.pack("<i", d.software_limits_counts[0])
    assert w[(0x607D, 2)] == struct.pack("<i", d.software_limits_counts[1])
    assert w[(0x1017, 0)] == struct.pack("<H", d.heartbeat_producer_ms)
    assert w[(0x1016, 1)] == struct.pack("<I", (127 << 16) | d.heartbeat_consumer_ms)


def test_epos2_ip_configuration_and_homing_objects():
    d = drive_cfgs(1, "epos2", "ip")[0]
    writes = epos.configuration_writes(d, bus_cfg("x", sync_period_s=0.005))
    w = {(x.index, x.sub): x.data for x in writes}
    # maxon's EPOS2 file: interpolation sub mode selection is 0x60C0 (-1 = PVT)
    assert w[(0x6060, 0)] == b"\x07" and w[(0x60C0, 0)] == struct.pack("<h", -1)
    # 5 ms is outside the EPOS2's 0x60C2:1 range (1..1): not written; no 0x6066/0x605A either
    assert (0x60C2, 1) not in w and (0x6066, 0) not in w and (0x605A, 0) not in w
    assert [x.data for x in writes if x.index == 0x60C4] == [b"\x00", b"\x01"]  # clear, enable
    h = DriveConfig(
        name="m",
        cable="c",
        node_id=1,
        type="epos2",
        mode="pp",
        counts_per_mm=1.0,
        homing={
            "method": -3,
            "current_threshold_mA": 800,
            "offset_counts": 500,
            "home_position_counts": -100,
        },
    )
    hw = {(x.index, x.sub): x.data for x in epos.homing_writes(h)}
    assert hw[(0x6098, 0)] == struct.pack("<b", -3)
    assert hw[(0x2080, 0)] == struct.pack("<H", 800)  # EPOS2 threshold
    assert hw[(0x2081, 0)] == struct.pack("<i", -100)  # EPOS2 home position
    assert hw[(0x607C, 0)] == struct.pack("<i", 500)
    h4 = h.model_copy(update={"type": "epos4"})
    hw4 = {(x.index, x.sub) for x in epos.homing_writes(h4)}
    assert {(0x30B2, 0), (0x30B1, 0), (0x30B0, 0)} <= hw4


def test_interpolation_period_must_be_whole_ms():
    d = drive_cfgs(1)[0]
    with pytest.raises(ConfigError, match="whole milliseconds"):
        epos.configuration_writes(d, bus_cfg("x", sync_period_s=0.0025), "rig.yaml")


def test_config_rules_per_family():
    with pytest.raises(ValidationError, match="no cyclic synchronous"):
        drive_cfgs(1, "epos2", "csp")
    with pytest.raises(ValidationError, match="EPOS4 has neither"):
        drive_cfgs(1, "epos4", "ip")
    assert drive_cfgs(1, "epos2", "pm")[0].mode == "pm"


def test_bus_kwargs_per_interface():
    assert bus_kwargs(bus_cfg("c", interface="slcan", channel="/dev/ttyACM0"))["bitrate"] == (
        1_000_000
    )
    assert "bitrate" not in bus_kwargs(bus_cfg("can0", interface="socketcan"))
    assert bus_kwargs(bus_cfg("c"))["receive_own_messages"] is False
    assert bus_kwargs(bus_cfg("PCAN_USBBUS1", interface="pcan", bitrate=500_000))["bitrate"] == (
        500_000
    )


# ------------------------------------------------------------------------------- heartbeat


def test_heartbeat_consumer_expiry_and_restart():
    hb = HeartbeatConsumer({1: 0.05, 2: 0.05, 3: 0.0})
    assert hb.expired(100.0) == []  # not armed yet
    hb.beat(1, 0x7F, 99.9)
    hb.arm(100.0)
    assert hb.beat(1, 0x05, 100.1) is None
    assert hb.beat(2, 0x05, 100.1) is None
    assert hb.expired(100.2) == []  # 3 x 50 ms
    assert [n for n, _ in hb.expired(100.26)] == [1, 2]  # node 3 is not watched
    assert hb.beat(1, 0x00, 100.3) == "boot-up message: the drive restarted"
    assert hb.beat(2, 0x7F, 100.3) == "NMT state changed to PRE-OPERATIONAL"
