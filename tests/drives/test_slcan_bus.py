"""SlcanBus, the line-at-a-time slcan interface: the same bytes as python-can's slcan on the wire,
the receive path (lines split across reads, adapter answers and junk dropped, filters before any
Message is made), one write per burst, a bounded write, and slcan over loopback TCP against the
simulated adapter."""

from __future__ import annotations

import os
import select
import time
import tty

import can
import pytest
from drivesim import assert_same_frame, can_messages, channel, wait_until
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.drives.slcan import SlcanBus, encode_data_line, encode_line, parse_line
from cdcr_ctl.sim.slcan_device import SlcanDevice, decode_frame, encode_frame


class Pty:
    """A raw pty pair: the bus under test on the slave side, the test on the master side."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)

    def read_all(self, settle_s: float = 0.05) -> bytes:
        out = b""
        while select.select([self.master], [], [], settle_s)[0]:
            out += os.read(self.master, 4096)
        return out

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def close(self) -> None:
        for fd in (self.master, self.slave):
            os.close(fd)


@pytest.fixture
def pty():
    p = Pty()
    yield p
    p.close()


def open_bus(path: str, cls: type = SlcanBus, **kw) -> can.BusABC:
    return cls(channel=path, bitrate=1_000_000, sleep_after_open=0, **kw)


messages = can_messages()


def test_set_up_and_frames_are_the_bytes_python_can_sends(pty):
    from can.interfaces.slcan import slcanBus

    sample = [
        can.Message(arbitration_id=0x201, data=bytes.fromhex("e8030000"), is_extended_id=False),
        can.Message(arbitration_id=0x080, data=b"", is_extended_id=False),
        can.Message(arbitration_id=0x1ABCDE, data=b"\x01\x02", is_extended_id=True),
        can.Message(arbitration_id=0x7FF, is_remote_frame=True, dlc=3, is_extended_id=False),
    ]
    stock = open_bus(pty.path, slcanBus)
    for m in sample:
        stock.send(m)
    stock.shutdown()
    want = pty.read_all()
    ours = open_bus(pty.path)
    # canopen logs "Connected to '<channel_info>'": the device, not BusABC's "unknown".
    assert stock.channel_info == "unknown" and ours.channel_info == pty.path
    for m in sample:
        ours.send(m)
    ours.shutdown()
    got = pty.read_all()
    assert got == want  # set-up (C, S8, O), the frames, the close (C), and nothing else
    assert b"t201" + b"4E8030000\r" in got and b"t0800\r" in got and b"r7FF3\r" in got


@settings(max_examples=200)
@given(messages)
def test_encode_line_matches_the_emulator_and_parses_back(msg):
    line = encode_line(msg)
    assert line == encode_frame(msg)  # the simulated adapter's encoder, written independently
    if not (msg.is_extended_id or msg.is_remote_frame):
        assert encode_data_line(msg.arbitration_id, bytes(msg.data)) == line
    back = parse_line(line[:-1].decode())
    assert_same_frame(back, msg)


@settings(max_examples=300)
@given(st.text(alphabet="tTrRdDbBxzZ0123456789ABCDEFabcdefG\a", max_size=24))
def test_parse_line_never_raises_and_agrees_with_the_emulator(line):
    msg = parse_line(line)
    ref = decode_frame(line)
    if ref is not None and line[:1] in "tTrR" and line[1:].upper() == line[1:]:
        assert msg is not None and msg.arbitration_id == ref.arbitration_id
        assert bytes(msg.data) == bytes(ref.data) and msg.dlc == ref.dlc
    if msg is not None:
        assert msg.dlc <= 64 and len(msg.data) <= 64


def test_receive_whole_lines_split_across_reads_answers_and_junk_dropped(pty):
    bus = open_bus(pty.path)
    try:
        pty.read_all()  # the set-up commands
        pty.write(b"z\rz\rZ\r\r\a")  # transmit acknowledgements, OK, BEL: no frames
        pty.write(b"t18160")  # half a frame ...
        assert bus.recv(0.05) is None
        pty.write(b"000E8030000\rtGGG0\rt1234AA\r")  # ... its end, junk, a short frame
        m = bus.recv(1.0)
        assert (m.arbitration_id, bytes(m.data)) == (0x181, bytes.fromhex("0000e8030000"))
        assert bus.recv(0.05) is None
        assert bus.bad_lines == 2  # tGGG0 and t1234AA (4 bytes announced, 1 given)
        pty.write(b"T000007018" + b"00" * 8 + b"\rr7FF0\r")
        m = bus.recv(1.0)
        assert m.is_extended_id and m.arbitration_id == 0x701 and m.dlc == 8
        m = bus.recv(1.0)
        assert m.is_remote_frame and m.arbitration_id == 0x7FF
    finally:
        bus.shutdown()


def test_filters_drop_frames_before_a_message_is_made(pty):
    bus = open_bus(pty.path)
    try:
        bus.set_filters([{"can_id": 0x181, "can_mask": 0x7FF, "extended": False}])
        pty.write(b"t2014E8030000\rt0800\rT000001811AA\rt1811BB\r")  # own echo, SYNC, ext, ours
        m = bus.recv(1.0)
        assert (m.arbitration_id, bytes(m.data)) == (0x181, b"\xbb")
        assert bus.recv(0.05) is None
        bus.set_filters([{"can_id": 0x100, "can_mask": 0x700}])  # not the full mask: generic
        pty.write(b"t1231CC\rt2231DD\r")
        m = bus.recv(1.0)
        assert (m.arbitration_id, bytes(m.data)) == (0x123, b"\xcc")
        assert bus.recv(0.05) is None
    finally:
        bus.shutdown()


def test_send_frames_is_one_write_in_order(pty):
    bus = open_bus(pty.path)
    try:
        pty.read_all()
        burst = [
            can.Message(
                arbitration_id=0x200 + n, data=n.to_bytes(4, "little"), is_extended_id=False
            )
            for n in (1, 2, 3)
        ] + [can.Message(arbitration_id=0x080, data=b"", is_extended_id=False)]
        bus.send_frames([(m.arbitration_id, bytes(m.data)) for m in burst], 0.005)
        want = b"".join(encode_line(m) for m in burst)
        assert os.read(pty.master, 4096) == want  # one read takes the whole burst
    finally:
        bus.shutdown()


class StallingPort:
    """Stands in for ``os``/``select`` in the slcan module: the port takes ``first`` bytes, then
    nothing until ``stall_s`` has passed, then everything; what it took is in ``out``."""

    def __init__(self, first: int, stall_s: float) -> None:
        self.first, self.stall_s = first, stall_s
        self.out = b""
        self.t0: float | None = None

    def write(self, fd: int, data: bytes) -> int:
        if self.t0 is None:
            self.t0 = time.monotonic()
            self.out += bytes(data[: self.first])
            return min(self.first, len(data))
        if time.monotonic() - self.t0 < self.stall_s:
            raise BlockingIOError
        self.out += bytes(data)
        return len(data)

    def select(self, r, w, x, timeout=None):
        time.sleep(min(timeout or 0.001, 0.001))
        return r, w, x

    def __getattr__(self, name):
        return getattr(os, name)


@pytest.mark.parametrize(
    ("first", "stall_s", "finished"),
    [(0, 10.0, False), (5, 0.1, True), (5, 10.0, False)],
    ids=["nothing-taken", "line-started-then-finished", "line-started-never-finished"],
)
def test_a_write_the_adapter_does_not_take_times_out_and_never_cuts_a_line(
    pty, monkeypatch, first, stall_s, finished
):
    import cdcr_ctl.drives.slcan as slcan_module

    bus = open_bus(pty.path)
    port = StallingPort(first, stall_s)
    monkeypatch.setattr(slcan_module, "os", port)
    monkeypatch.setattr(slcan_module, "select", port)
    monkeypatch.setattr(slcan_module, "PARTIAL_LINE_S", 0.3)
    burst = [
        can.Message(arbitration_id=0x201, data=b"\x01\x02\x03\x04", is_extended_id=False),
        can.Message(arbitration_id=0x080, data=b"", is_extended_id=False),
    ]
    try:
        t0 = time.monotonic()
        with pytest.raises(can.CanTimeoutError):
            bus.send_frames([(m.arbitration_id, bytes(m.data)) for m in burst], 0.02)
        assert time.monotonic() - t0 < 2.0
        line = encode_line(burst[0])
        # Whole lines or nothing: the line started is finished when the port takes it within
        # PARTIAL_LINE_S, and the burst's next line is not sent after a timeout.
        assert port.out == (line if finished else line[:first])
    finally:
        monkeypatch.undo()
        bus.shutdown()


def test_slcan_over_loopback_tcp_against_the_simulated_adapter():
    ch = channel()
    inner = can.Bus(interface="virtual", channel=ch)
    other = can.Bus(interface="virtual", channel=ch)
    dev = SlcanDevice(inner, tcp=True)
    try:
        assert dev.path.startswith("socket://127.0.0.1:")
        for _ in range(2):  # a second host connects after the first went away
            bus = open_bus(dev.path)
            try:
                bus.send(can.Message(arbitration_id=0x601, data=b"\x40", is_extended_id=False))
                m = other.recv(1.0)
                assert (m.arbitration_id, bytes(m.data)) == (0x601, b"\x40")
                other.send(can.Message(arbitration_id=0x581, data=b"\x60", is_extended_id=False))
                got = bus.recv(1.0)
                assert (got.arbitration_id, bytes(got.data)) == (0x581, b"\x60")
            finally:
                bus.shutdown()
            assert wait_until(lambda: dev.master_fd < 0)
    finally:
        dev.stop()
        inner.shutdown()
        other.shutdown()


def test_a_closed_adapter_is_a_receive_error_not_a_silence():
    ch = channel()
    inner = can.Bus(interface="virtual", channel=ch)
    dev = SlcanDevice(inner, tcp=True)
    bus = open_bus(dev.path)
    try:
        dev.unplug()
        with pytest.raises(can.CanOperationError, match=r"disconnected|read"):
            end = time.monotonic() + 2.0
            while time.monotonic() < end:
                bus.recv(0.1)
    finally:
        bus.shutdown()
        inner.shutdown()


def test_frame_hook_takes_its_frames_without_a_message(pty):
    got = []
    bus = open_bus(pty.path)
    try:
        bus.set_frame_hook([0x181, 0x182], lambda cid, data, ts: got.append((cid, data)))
        pty.write(b"t18160000E8030000\rt1831AA\rt1826370600000000\rt181\rt7011" + b"05\r")
        m = bus.recv(1.0)
        assert (m.arbitration_id, bytes(m.data)) == (0x183, b"\xaa")
        m = bus.recv(1.0)
        assert m.arbitration_id == 0x701
        assert bus.recv(0.05) is None
        assert got == [
            (0x181, bytes.fromhex("0000e8030000")),
            (0x182, bytes.fromhex("370600000000")),
        ]
        assert bus.bad_lines == 1  # the truncated t181
        bus.set_frame_hook([0x181], None)
        pty.write(b"t18110F\r")
        m = bus.recv(1.0)
        assert (m.arbitration_id, bytes(m.data)) == (0x181, b"\x0f") and len(got) == 2
    finally:
        bus.shutdown()


def test_drive_group_over_slcan_tcp_to_in_process_drives_logs_its_traffic(tmp_path):
    """The group's TPDOs come through the hook; the frame ring and the traffic log still have
    them; the simulated adapter hands frames to the nodes directly."""
    from drivesim import Cycler, drive_cfgs

    from cdcr_ctl.config.drives import CanBusConfig
    from cdcr_ctl.drives.canbus import open_bus as open_cfg_bus
    from cdcr_ctl.drives.group import DriveGroup
    from cdcr_ctl.sim.epos.rig import SimDriveBus

    drives = drive_cfgs(2)
    sim = SimDriveBus(drives, "slcan", tcp=True).start()
    cfg = CanBusConfig(
        interface="slcan", channel=sim.channel_path, sync_period_s=0.005, feedback_timeout_s=0.25
    )
    try:
        with DriveGroup(open_cfg_bus(cfg), cfg, drives) as g:
            assert isinstance(g.network.bus, SlcanBus)
            g.boot()
            g.configure()
            g.log_traffic(tmp_path / "can.asc")
            with Cycler(g) as cyc:
                g.enable()
                cyc.targets = [1500, -700]
                assert wait_until(lambda: [f.position_counts for f in g.feedback()] == [1500, -700])
            g.log_traffic(None)
            assert g.first_fault() is None
            assert " rx 181 [6]" in g.frame_dump() and " tx 080 [0]" in g.frame_dump()
        log_text = (tmp_path / "can.asc").read_text()
        assert "181             Rx   d 6" in log_text and "201             Tx   d 4" in log_text
        assert sim.actual_positions() == [1500, -700]
    finally:
        sim.stop()
