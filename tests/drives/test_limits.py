"""Object limits from maxon's device descriptions: every planned SDO write is checked before the
first CAN frame, against the shipped table or a device description file the config names; the
simulated drive refuses what the real one refuses; homing objects as maxon defines them, byte by
byte on the wire."""

from __future__ import annotations

import struct

import can
import canopen
import pytest
from canopen.objectdictionary import ObjectDictionary, ODRecord, ODVariable, export_od
from canopen.sdo.exceptions import SdoAbortedError
from drivesim import bus_cfg, channel, collect, drain, drive_cfgs, make_rig

from cdcr_ctl.config.drives import DriveConfig
from cdcr_ctl.drives import epos
from cdcr_ctl.drives.group import DriveGroup
from cdcr_ctl.drives.limits import (
    ABORT_NO_OBJECT,
    ABORT_READ_ONLY,
    ABORT_VALUE_TOO_HIGH,
    EPOS4_OBJECTS,
    check_write,
    shipped_table,
)
from cdcr_ctl.drives.plan import check_plans
from cdcr_ctl.errors import ConfigError
from cdcr_ctl.sim.epos.rig import SimDriveBus


def refused_before_any_frame(drives: list[DriveConfig], file: str = "rig.yaml", **bus_kw):
    """Make a group on a fresh channel; return its ConfigError and the frames a spy saw."""
    ch = channel()
    spy = can.Bus(interface="virtual", channel=ch)
    try:
        with pytest.raises(ConfigError) as exc:
            DriveGroup(
                can.Bus(interface="virtual", channel=ch), bus_cfg(ch, **bus_kw), drives, file=file
            )
        return exc.value, collect(spy, 0.05)
    finally:
        spy.shutdown()


# ------------------------------------------------------------------ the shipped table
def test_maxon_limits_as_the_files_give_them():
    e4, e2 = shipped_table("epos4"), shipped_table("epos2")
    assert (e4.get(0x6066, 0).low, e4.get(0x6066, 0).high) == (0, 0)
    assert (e4.get(0x60C2, 1).low, e4.get(0x60C2, 1).high) == (0, 100)
    assert e4.get(0x30B0, 0).name == "Home position"
    assert e4.get(0x30B1, 0).name == "Home offset move distance"
    assert not e2.has(0x6066) and not e2.has(0x605A) and e2.has(0x60C0)
    assert check_write(e4, 0x6066, 0, struct.pack("<H", 10)).code == ABORT_VALUE_TOO_HIGH
    assert check_write(e4, 0x6041, 0, struct.pack("<H", 6)).code == ABORT_READ_ONLY
    assert check_write(e2, 0x6066, 0, struct.pack("<H", 0)).code == ABORT_NO_OBJECT
    assert check_write(e4, 0x6066, 0, struct.pack("<H", 0)) is None


def test_default_config_passes_the_epos4_and_epos2_tables():
    for kind, mode in (("epos4", "csp"), ("epos4", "pp"), ("epos2", "pp"), ("epos2", "ip")):
        check_plans(drive_cfgs(2, kind, mode), bus_cfg("x", sync_period_s=0.004), "rig.yaml")


def test_out_of_range_following_error_timeout_refused_before_any_frame():
    err, frames = refused_before_any_frame(drive_cfgs(2, following_error_timeout_ms=10))
    assert err.file == "rig.yaml"
    assert err.key == "drives[name=m1].following_error_timeout_ms"
    assert "0x6066:00" in str(err) and "0x06090031" in str(err) and "0..0" in str(err)
    assert frames == []


def test_interpolation_period_outside_0x60c2_range_refused():
    err, frames = refused_before_any_frame(drive_cfgs(1), sync_period_s=0.2)
    assert err.key == "can.sync_period_s" and "0x60C2:1" in str(err) and "0..100" in str(err)
    assert frames == []


def test_epos2_option_code_it_lacks_is_refused_when_set():
    err, frames = refused_before_any_frame(
        drive_cfgs(1, "epos2", "pp", quick_stop_option_code=6), sync_period_s=0.004
    )
    assert err.key == "drives[name=m1].quick_stop_option_code"
    assert "0x605A:00" in str(err) and "no such object" in str(err)
    assert frames == []


def test_homing_current_threshold_above_range_refused():
    d = drive_cfgs(1, homing={"method": -3, "current_threshold_mA": 6000})
    err, frames = refused_before_any_frame(d)
    assert err.key == "drives[name=m1].homing.current_threshold_mA"
    assert "0x30B2:00" in str(err) and "0..5000" in str(err)
    assert frames == []


# ------------------------------------------------------------------ a device description file
def write_eds(path, changes: dict[tuple[int, int], dict]) -> None:
    """A small EDS of this test's own: the shipped EPOS4 objects, with ``changes`` applied to
    (index, sub) (attribute -> value), written by canopen's exporter."""
    od = ObjectDictionary()
    od.device_information.vendor_name = "test"
    od.device_information.product_name = "EPOS4 (test description)"
    by_index: dict[int, list] = {}
    for o in EPOS4_OBJECTS:
        by_index.setdefault(o.index, []).append(o)
    for index, objs in sorted(by_index.items()):

        def var(o) -> ODVariable:
            v = ODVariable(o.name, o.index, o.sub)
            v.data_type, v.access_type, v.min, v.max = o.dtype, o.access, o.low, o.high
            v.default = 0
            for attr, value in changes.get((o.index, o.sub), {}).items():
                setattr(v, attr, value)
            return v

        if len(objs) == 1 and objs[0].sub == 0:
            od.add_object(var(objs[0]))
        else:
            rec = ODRecord(objs[0].name, index)
            for o in sorted(objs, key=lambda o: o.sub):
                rec.add_member(var(o))
            od.add_object(rec)
    export_od(od, str(path), doc_type="eds")


def test_read_only_object_in_a_device_description_refused(tmp_path):
    eds = tmp_path / "drive.eds"
    write_eds(eds, {(0x6065, 0): {"access_type": "ro"}})
    cfg = tmp_path / "rig.yaml"
    drives = drive_cfgs(2, eds="drive.eds")  # relative to the config file
    err, frames = refused_before_any_frame(drives, file=str(cfg))
    assert err.file == str(cfg)
    assert err.key == "drives[name=m1].following_error_window_counts"
    assert "0x6065:00" in str(err) and "not writable" in str(err) and "0x06010002" in str(err)
    assert frames == []


def test_out_of_range_value_in_a_device_description_refused(tmp_path):
    eds = tmp_path / "drive.eds"
    write_eds(eds, {(0x1017, 0): {"min": 0, "max": 40}})  # a drive whose heartbeat is 0-40 ms
    err, frames = refused_before_any_frame(drive_cfgs(1, eds=str(eds)), file="rig.yaml")
    assert err.key == "drives[name=m1].heartbeat_producer_ms"
    assert "0x1017:00" in str(err) and "50 above its range 0..40" in str(err)
    assert frames == []


def test_missing_device_description_names_the_key(tmp_path):
    err, frames = refused_before_any_frame(
        drive_cfgs(1, eds="nowhere.eds"), file=str(tmp_path / "r.yaml")
    )
    assert err.key == "drives[name=m1].eds" and "no such file" in str(err)
    assert frames == []


def test_group_configures_against_a_device_description_that_accepts(tmp_path):
    eds = tmp_path / "drive.eds"
    write_eds(eds, {})
    r = make_rig(drive_cfgs(2, eds=str(eds)))
    try:
        assert [n.mode for n in r.sim.nodes] == [8, 8]
    finally:
        r.close()


# ------------------------------------------------------------------ the simulated drive
def test_simulated_drive_refuses_what_the_real_one_refuses():
    ch = channel()
    sim = SimDriveBus([(1, "epos4"), (2, "epos2")], "virtual", ch).start()
    net = canopen.Network()
    net.connect(interface="virtual", channel=ch)
    try:
        n1 = net.add_node(1, ObjectDictionary())
        n2 = net.add_node(2, ObjectDictionary())
        for n in (n1, n2):
            n.sdo.RESPONSE_TIMEOUT = 2.0
        cases = [
            (n1, 0x6066, struct.pack("<H", 10), 0x06090031),  # range 0..0
            (n1, 0x60C2, b"\x96", 0x06090031),  # sub 1: 150 ms > 100
            (n1, 0x6041, struct.pack("<H", 0), 0x06010002),  # statusword is read only
            (n2, 0x6066, struct.pack("<H", 0), 0x06020000),  # the EPOS2 has none
        ]
        for node, index, data, code in cases:
            sub = 1 if index == 0x60C2 else 0
            with pytest.raises(SdoAbortedError) as exc:
                node.sdo.download(index, sub, data)
            assert exc.value.code == code, hex(index)
        n1.sdo.download(0x6066, 0, struct.pack("<H", 0))  # in range: accepted
    finally:
        net.disconnect()
        sim.stop()


# ------------------------------------------------------------------ homing objects on the wire
def test_epos4_home_with_offset_and_home_position_byte_by_byte():
    """0x30B0 = home position, 0x30B1 = home offset move distance (maxon's EPOS4 file): the
    SDO downloads on the wire, and the simulated drive homes to them."""
    homing = {"method": 37, "offset_counts": 500, "home_position_counts": -100}
    r = make_rig(drive_cfgs(1, homing=homing))
    try:
        drain(r.spy, 0.02, max_s=0.5)
        assert r.group.home() == [-100]
        frames = [(m.arbitration_id, bytes(m.data)) for m in drain(r.spy, 0.02, max_s=0.5)]
        # expedited download, 4 bytes (0x23), index LE, sub 0, int32 LE
        assert (0x601, bytes.fromhex("23b13000f4010000")) in frames  # 0x30B1 = 500
        assert (0x601, bytes.fromhex("23b030009cffffff")) in frames  # 0x30B0 = -100
        assert (0x581, bytes.fromhex("60b1300000000000")) in frames
        assert (0x581, bytes.fromhex("60b0300000000000")) in frames
        node = r.sim.node(1)
        assert node._value(epos.EPOS4_HOME_POSITION) == -100
        assert node._value(epos.EPOS4_HOME_OFFSET_MOVE) == 500
        assert node.position_counts == -100
    finally:
        r.close()


def test_epos2_home_with_offset_and_home_position_byte_by_byte():
    homing = {"method": 37, "offset_counts": 300, "home_position_counts": 70}
    r = make_rig(drive_cfgs(1, "epos2", "pp", homing=homing), sync_period_s=0.005)
    try:
        drain(r.spy, 0.02, max_s=0.5)
        assert r.group.home() == [70]
        frames = [(m.arbitration_id, bytes(m.data)) for m in drain(r.spy, 0.02, max_s=0.5)]
        assert (0x601, bytes.fromhex("237c60002c010000")) in frames  # 0x607C home offset = 300
        assert (0x601, bytes.fromhex("2381200046000000")) in frames  # 0x2081 home position = 70
        assert not [f for f in frames if f[0] == 0x601 and f[1][1:3] in (b"\xb0\x30", b"\xb1\x30")]
    finally:
        r.close()


def test_check_config_refuses_what_the_drive_would(tmp_path, capsys):
    from drivesim import ROOT

    from cdcr_ctl.cli.main import main

    cfg = tmp_path / "rig.yaml"
    drives = "\n".join(
        f"  - {{name: m{i}, cable: c{i}, node_id: {i}, counts_per_mm: 1238.6"
        + (", following_error_timeout_ms: 10}" if i == 2 else "}")
        for i in (1, 2, 3)
    )
    cfg.write_text(f"extends: {ROOT / 'config' / 'qi2023.yaml'}\ndrives:\n{drives}\n")
    assert main(["check-config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert f"{cfg}: drives[name=m2].following_error_timeout_ms" in err and "0x6066:00" in err
