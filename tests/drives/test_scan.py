"""``cdcr-ctl scan`` against the simulated rig: lists its nodes with device type and identity and
flags what differs from the config (missing node, wrong product, wrong node id); byte-level
checks of the requests it sends."""

from __future__ import annotations

import json

import can
from drivesim import ROOT, channel, collect, drive_cfgs

from cdcr_ctl.cli.main import main
from cdcr_ctl.drives.scan import compare, parse_upload_answer, scan_bus, upload_request
from cdcr_ctl.sim.epos.od import DEVICE_TYPE, PRODUCT_CODE
from cdcr_ctl.sim.epos.rig import SimDriveBus


def test_upload_request_and_answers_byte_by_byte():
    assert upload_request(5, 0x1000, 0) == (0x605, bytes.fromhex("4000100000000000"))
    # expedited, size given, 4 bytes (0x43): the value
    assert parse_upload_answer(bytes.fromhex("4300100092010200"), 0x1000, 0) == (True, 0x20192)
    # abort: the node exists without the object
    assert parse_upload_answer(bytes.fromhex("8000100000000206"), 0x1000, 0) == (True, None)
    assert parse_upload_answer(bytes.fromhex("4318100192010200"), 0x1000, 0) is None  # other
    assert parse_upload_answer(b"\x43\x00", 0x1000, 0) is None  # junk


def test_scan_lists_the_simulated_nodes_without_touching_them():
    ch = channel()
    sim = SimDriveBus([(1, "epos4"), (3, "epos2")], "virtual", ch).start()
    bus = can.Bus(interface="virtual", channel=ch)
    spy = can.Bus(interface="virtual", channel=ch)
    try:
        nodes = scan_bus(bus, timeout_s=0.3)
        sent = [m for m in collect(spy, 0.05) if m.arbitration_id < 0x580]
    finally:
        bus.shutdown()
        spy.shutdown()
        sim.stop()
    assert [n.node_id for n in nodes] == [1, 3]
    assert [n.family for n in nodes] == ["epos4", "epos2"]
    assert all(n.device_type == DEVICE_TYPE and n.vendor_id == 0xFB for n in nodes)
    assert [n.product_code for n in nodes] == [PRODUCT_CODE["epos4"], PRODUCT_CODE["epos2"]]
    assert nodes[0].serial == 0x1001
    # read only: SDO upload requests (0x40) only, no NMT, no download
    assert all(0x601 <= m.arbitration_id <= 0x67F for m in sent)
    assert all(m.data[0] in (0x40, 0x60, 0x70) for m in sent)


def test_compare_flags_missing_wrong_product_and_wrong_node_id():
    ch = channel()
    sim = SimDriveBus([(1, "epos4"), (2, "epos2"), (7, "epos4")], "virtual", ch).start()
    bus = can.Bus(interface="virtual", channel=ch)
    try:
        nodes = scan_bus(bus, timeout_s=0.3)
    finally:
        bus.shutdown()
        sim.stop()
    issues = compare(nodes, drive_cfgs(3))  # m1-m3: EPOS4 at nodes 1-3
    assert issues[0].startswith("missing: drive m3 (epos4, node 3) did not answer")
    assert "an EPOS4 answers at node 7: wrong node id?" in issues[0]
    assert any(i.startswith("wrong product: node 2") and "EPOS2" in i for i in issues)
    assert any(i.startswith("extra: node 7") for i in issues)
    assert compare(nodes[:1], drive_cfgs(1)) == []


def test_scan_command_against_the_simulated_rig(tmp_path, capsys):
    ch = channel()
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        f"extends: {ROOT / 'config' / 'qi2023.yaml'}\ncan:\n  interface: virtual\n  channel: {ch}\n"
    )
    sim = SimDriveBus([(1, "epos4"), (2, "epos4")], "virtual", ch).start()  # node 3 lacks
    try:
        code = main(["--config", str(cfg), "--json", "scan"])
        out = json.loads(capsys.readouterr().out)
        assert code == 1
        assert [n["node_id"] for n in out["nodes"]] == [1, 2]
        assert out["nodes"][0]["device_type"] == "0x00020192"
        assert out["nodes"][0]["vendor_id"] == "0x000000FB"
        assert out["issues"] == ["missing: drive m3 (epos4, node 3) did not answer"]
    finally:
        sim.stop()
    sim = SimDriveBus([(1, "epos4"), (2, "epos4"), (3, "epos4")], "virtual", ch).start()
    try:
        assert main(["--config", str(cfg), "scan"]) == 0
        text = capsys.readouterr().out
        assert "3 node(s)" in text and "matches the config" in text
    finally:
        sim.stop()


def test_scan_refuses_while_another_process_owns_the_bus(tmp_path, capsys):
    """A daemon's bus lock (cdcr_ctl.ownership) held by another process: scan says who owns
    the bus and sends nothing (the simulated nodes see no frame); options after the command."""
    import subprocess
    import sys

    from cdcr_ctl.ownership import bus_key

    ch = channel()
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        f"extends: {ROOT / 'config' / 'qi2023.yaml'}\ncan:\n  interface: virtual\n  channel: {ch}\n"
    )
    hold = (
        "import sys; from cdcr_ctl.ownership import Ownership; o = Ownership(); "
        f"o.take({bus_key('virtual', ch)!r}); print('held', flush=True); sys.stdin.read()"
    )
    owner = subprocess.Popen(
        [sys.executable, "-c", hold], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    sim = SimDriveBus([(1, "epos4"), (2, "epos4"), (3, "epos4")], "virtual", ch).start()
    probe = can.Bus(interface="virtual", channel=ch, receive_own_messages=False)
    try:
        assert owner.stdout is not None and owner.stdout.readline().strip() == "held"
        while probe.recv(0.05) is not None:  # the nodes' boot-up messages
            pass
        assert main(["scan", "--config", str(cfg), "--json"]) == 1
        err = capsys.readouterr().err
        assert f"already running (pid {owner.pid};" in err, err
        assert probe.recv(0.2) is None  # not one frame on the bus
        owner.communicate("")
        assert main(["scan", "-c", str(cfg), "--json"]) == 0  # the owner gone: the scan runs
        assert json.loads(capsys.readouterr().out)["matches_config"] is True
    finally:
        probe.shutdown()
        sim.stop()
        if owner.poll() is None:
            owner.kill()
            owner.wait()
