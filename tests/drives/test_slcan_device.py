"""The simulated USB-CAN adapter: the Lawicel/slcan ASCII protocol on a pty, byte by byte, and
python-can's own slcan interface talking to it."""

from __future__ import annotations

import os
import select
import time

import can
import pytest
from drivesim import assert_same_frame, can_messages, channel, wait_until
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.sim.slcan_device import SlcanDevice, decode_frame, encode_frame


class Host:
    """The host side of the pty, raw bytes."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)

    def ask(self, data: bytes, timeout_s: float = 1.0) -> bytes:
        os.write(self.fd, data)
        return self.read(timeout_s)

    def read(self, timeout_s: float = 1.0, until: tuple[bytes, ...] = (b"\r", b"\a")) -> bytes:
        out = b""
        end = time.monotonic() + timeout_s
        while not out.endswith(until) and (left := end - time.monotonic()) > 0:
            ready, _, _ = select.select([self.fd], [], [], left)
            if ready:
                out += os.read(self.fd, 1)
        return out

    def close(self) -> None:
        os.close(self.fd)


@pytest.fixture
def adapter():
    ch = channel()
    bus = can.Bus(interface="virtual", channel=ch)
    dev = SlcanDevice(bus, bitrate=1_000_000)
    other = can.Bus(interface="virtual", channel=ch)
    host = Host(dev.path)
    yield dev, host, other
    host.close()
    dev.stop()
    bus.shutdown()
    other.shutdown()


def test_version_serial_bitrate_open_close(adapter):
    dev, host, _ = adapter
    assert host.ask(b"V\r") == b"V1013\r"
    assert host.ask(b"v\r") == b"v1013\r"
    assert host.ask(b"N\r") == b"NCDCR\r"
    assert host.ask(b"F\r") == b"\a"  # status only while open
    assert host.ask(b"C\r") == b"\a"  # not open
    assert host.ask(b"S9\r") == b"\a"  # no such Lawicel rate
    assert host.ask(b"S8\r") == b"\r"
    assert host.ask(b"\r") == b"\r"  # python-can sends an empty command after Sn
    assert host.ask(b"Z1\r") == b"\r"
    assert host.ask(b"O\r") == b"\r"
    assert host.ask(b"O\r") == b"\a"  # already open
    assert host.ask(b"S6\r") == b"\a"  # bit rate only while closed
    assert host.ask(b"F\r") == b"F00\r"
    assert host.ask(b"C\r") == b"\r"
    assert dev.bad_commands == 5


def test_frames_both_ways(adapter):
    dev, host, other = adapter
    assert host.ask(b"O\r") == b"\r"
    assert host.ask(b"t1232AABB\r") == b"z\r"
    m = other.recv(1.0)
    assert (m.arbitration_id, m.is_extended_id, bytes(m.data)) == (0x123, False, b"\xaa\xbb")
    assert host.ask(b"T1234567880011223344556677\r") == b"Z\r"
    m = other.recv(1.0)
    assert (m.arbitration_id, m.is_extended_id, m.dlc) == (0x12345678, True, 8)
    assert host.ask(b"r7FF0\r") == b"z\r"
    m = other.recv(1.0)
    assert m.is_remote_frame and m.arbitration_id == 0x7FF
    other.send(
        can.Message(arbitration_id=0x181, data=bytes.fromhex("3716e8030000"), is_extended_id=False)
    )
    assert host.read() == b"t18163716E8030000\r"
    for junk in (b"t12\r", b"t1232AAB\r", b"t8000\r", b"t1239\r", b"x\r", b"tGGG0\r"):
        assert host.ask(junk) == b"\a"
    assert dev.rx_frames == 3 and dev.tx_frames == 1


def test_timestamps_listen_only_and_wrong_bit_rate(adapter):
    _dev, host, other = adapter
    assert host.ask(b"Z1\r") == b"\r"
    assert host.ask(b"L\r") == b"\r"  # listen only
    other.send(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False))
    line = host.read()
    assert line.startswith(b"t701105") and len(line) == len(b"t701105") + 4 + 1  # + ms stamp
    assert host.ask(b"t0010\r") == b"\a"  # a listening adapter does not transmit
    assert host.ask(b"C\r") == b"\r"
    assert host.ask(b"Z0\r") == b"\r"
    assert host.ask(b"S6\r") == b"\r"  # 500 kbit/s on a 1 Mbit/s bus
    assert host.ask(b"O\r") == b"\r"
    other.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
    assert host.ask(b"t0010\r") == b"z\r"  # into the FIFO, but never onto the bus
    assert other.recv(0.1) is None
    assert host.ask(b"F\r") == b"FA0\r"  # bus error + error passive
    assert host.ask(b"F\r") == b"F00\r"  # flags clear on reading


def test_junk_without_carriage_return_is_dropped(adapter):
    dev, host, _ = adapter
    assert host.ask(b"Q" * 70) == b"\a"
    assert host.ask(b"V\r") == b"V1013\r"
    assert dev.bad_commands == 1


def test_python_can_slcan_interface_talks_to_it():
    ch = channel()
    inner = can.Bus(interface="virtual", channel=ch)
    dev = SlcanDevice(inner, bitrate=500_000)
    other = can.Bus(interface="virtual", channel=ch)
    host = can.Bus(interface="slcan", channel=dev.path, bitrate=500_000, sleep_after_open=0)
    try:
        assert host.get_version(1.0) == (10, 13)
        assert host.get_serial_number(1.0) == "CDCR"
        host.send(
            can.Message(
                arbitration_id=0x601, data=bytes.fromhex("4000100000000000"), is_extended_id=False
            )
        )
        m = other.recv(1.0)
        assert m.arbitration_id == 0x601 and bytes(m.data) == bytes.fromhex("4000100000000000")
        other.send(
            can.Message(
                arbitration_id=0x581, data=bytes.fromhex("4300100092010200"), is_extended_id=False
            )
        )
        got = None
        end = time.monotonic() + 2
        while got is None and time.monotonic() < end:
            got = host.recv(0.1)  # the z acknowledgements come first and are skipped
        assert got.arbitration_id == 0x581 and bytes(got.data) == bytes.fromhex("4300100092010200")
        assert dev.bitrate == 500_000 and dev.is_open
    finally:
        host.shutdown()
        dev.stop()
        inner.shutdown()
        other.shutdown()


messages = can_messages()


@given(messages)
def test_encode_decode_round_trip(msg):
    line = encode_frame(msg).decode()
    assert line.endswith("\r")
    back = decode_frame(line[:-1])
    assert_same_frame(back, msg)


@pytest.fixture(scope="module")
def idle_device():
    bus = can.Bus(interface="virtual", channel=channel())
    dev = SlcanDevice(bus)
    yield dev
    dev.stop()
    bus.shutdown()


@settings(max_examples=300)
@given(st.text(alphabet="tTrRSsOLCVvNFZMmx0123456789ABCDEFabcdef\n", max_size=30))
def test_any_command_line_gets_a_lawicel_answer(idle_device, line):
    answer = idle_device.command(line)
    allowed = (b"\r", b"\a", b"z\r", b"Z\r", b"V1013\r", b"v1013\r", b"NCDCR\r")
    assert answer in allowed or (answer.startswith(b"F") and len(answer) == 4)


def test_deliver_mode_answers_and_the_frames_they_trigger_come_in_one_write():
    """The nodes' dispatcher is called in the reader thread; what the nodes send meanwhile (the
    TPDOs a SYNC triggers) goes to the host after the acknowledgements, in the same write."""
    delivered = []

    def deliver(msg: can.Message) -> None:
        delivered.append((msg.arbitration_id, bytes(msg.data)))
        if msg.arbitration_id == 0x080:  # SYNC: two nodes answer
            for node in (1, 2):
                dev.on_message_received(
                    can.Message(arbitration_id=0x180 + node, data=b"\x37\x06", is_extended_id=False)
                )

    dev = SlcanDevice(None, deliver=deliver)
    host = Host(dev.path)
    try:
        assert host.ask(b"O\r") == b"\r"
        os.write(host.fd, b"t2014E8030000\rt0800\r")  # a set-point and SYNC in one write
        end = time.monotonic() + 2.0
        got = b""
        while not got.endswith(b"t18223706\r") and time.monotonic() < end:
            if select.select([host.fd], [], [], 0.1)[0]:
                got += os.read(host.fd, 4096)
        assert got == b"z\rz\rt18123706\rt18223706\r"
        assert delivered == [(0x201, bytes.fromhex("e8030000")), (0x080, b"")]
        assert dev.rx_frames == 2
        assert wait_until(lambda: dev.tx_frames == 2)  # counted once the write returned
        # A frame from another thread (a heartbeat) goes out on its own.
        dev.on_message_received(
            can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False)
        )
        assert host.read() == b"t701105\r"
    finally:
        host.close()
        dev.stop()


def test_a_device_needs_a_bus_or_a_dispatcher_and_a_tcp_one_has_no_pty_link(tmp_path):
    with pytest.raises(ValueError, match="one of them"):
        SlcanDevice(None)
    with pytest.raises(ValueError, match="address"):
        SlcanDevice(None, tmp_path / "can", deliver=lambda m: None, tcp=True)
