"""cdcr_ctl.seriallink: the ``socket://`` handler the drive and sensor layers open TCP links
with (the simulated rig's slcan adapter and load cells): pyserial's, without its close sleep."""

from __future__ import annotations

import socket

import pytest
import serial
from serial.urlhandler import protocol_socket as pyserial_socket

from cdcr_ctl import seriallink
from cdcr_ctl.seriallink import protocol_socket


@pytest.fixture
def listener():
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    srv.settimeout(5.0)
    yield srv, f"socket://127.0.0.1:{srv.getsockname()[1]}"
    srv.close()


def test_register_puts_the_package_first_once(monkeypatch):
    monkeypatch.setattr(serial, "protocol_handler_packages", ["serial.urlhandler"])
    seriallink.register()
    seriallink.register()
    assert serial.protocol_handler_packages == [seriallink.PACKAGE, "serial.urlhandler"]


def test_socket_url_opens_the_handler_and_closes_without_sleeping(monkeypatch, listener):
    srv, url = listener
    monkeypatch.setattr(serial, "protocol_handler_packages", ["serial.urlhandler"])
    seriallink.register()

    def no_sleep(s: float) -> None:
        raise AssertionError(f"close slept {s} s")

    # pyserial's own close sleeps through this module's time.sleep: a sleep would raise here.
    monkeypatch.setattr(pyserial_socket.time, "sleep", no_sleep)
    port = serial.serial_for_url(url, timeout=1.0)
    assert type(port) is protocol_socket.Serial
    peer, _ = srv.accept()
    peer.settimeout(5.0)
    port.write(b"t1230\r")
    assert peer.recv(16) == b"t1230\r"
    peer.sendall(b"z\r")
    assert port.read(2) == b"z\r"
    port.close()
    assert not port.is_open
    assert peer.recv(16) == b""  # the peer sees the end at once
    port.close()  # closing a closed port is a no-op, as pyserial's
    peer.close()


def test_other_urls_keep_pyserials_handlers(monkeypatch):
    monkeypatch.setattr(serial, "protocol_handler_packages", ["serial.urlhandler"])
    seriallink.register()
    port = serial.serial_for_url("loop://", timeout=0.1)
    try:
        assert type(port).__module__ == "serial.urlhandler.protocol_loop"
    finally:
        port.close()
