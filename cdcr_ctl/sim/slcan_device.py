"""A simulated USB-CAN adapter: the Lawicel/slcan ASCII protocol on a pseudo-terminal.

The simulated rig owns the pty's master side and a python-can bus (usually ``virtual``) holding the
simulated nodes; a controller in another process opens the pty's slave side with python-can's
``slcan`` interface, exactly as it would open a real adapter (``/dev/ttyACM0``).

Host -> adapter commands: ``O`` open, ``C`` close, ``L`` listen-only, ``S0``-``S8`` bit rate,
``V``/``v``/``N`` version and serial, ``F`` status flags, ``Z0``/``Z1`` timestamps, and frames
``tIIILDD..``, ``TIIIIIIIILDD..``, ``rIIIL``, ``RIIIIIIIIL``. Answers: ``\\r`` (OK) or ``\\a``
(error); transmitted frames are acknowledged ``z\\r``/``Z\\r``. Adapter -> host: every frame seen on
the bus as ``t``/``T``/``r``/``R`` lines. Frames are only relayed while the channel is open.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import threading
import tty
from pathlib import Path

import can

log = logging.getLogger(__name__)

OK, ERROR = b"\r", b"\a"


def encode_frame(msg: can.Message) -> bytes:
    """One slcan line for ``msg`` (without timestamp)."""
    if msg.is_extended_id:
        head = f"{'R' if msg.is_remote_frame else 'T'}{msg.arbitration_id:08X}{msg.dlc}"
    else:
        head = f"{'r' if msg.is_remote_frame else 't'}{msg.arbitration_id:03X}{msg.dlc}"
    body = "" if msg.is_remote_frame else bytes(msg.data).hex().upper()
    return (head + body).encode() + b"\r"


def decode_frame(line: str) -> can.Message | None:
    """An slcan frame command -> Message; None when malformed."""
    try:
        kind = line[0]
        ext = kind in "TR"
        id_len = 8 if ext else 3
        can_id = int(line[1 : 1 + id_len], 16)
        dlc = int(line[1 + id_len])
        if not 0 <= dlc <= 8 or (not ext and can_id > 0x7FF):
            return None
        remote = kind in "rR"
        data = b"" if remote else bytes.fromhex(line[2 + id_len : 2 + id_len + 2 * dlc])
        if not remote and len(data) != dlc:
            return None
        return can.Message(
            arbitration_id=can_id, is_extended_id=ext, is_remote_frame=remote, dlc=dlc, data=data
        )
    except (ValueError, IndexError):
        return None


class SlcanDevice(can.Listener):
    """The adapter: pty master <-> ``bus``. ``path`` is the slave side (or ``link`` to it)."""

    def __init__(self, bus: can.BusABC, link: str | Path | None = None) -> None:
        self.bus = bus
        self.master_fd, self.slave_fd = os.openpty()
        tty.setraw(self.slave_fd)
        self.pty_path = os.ttyname(self.slave_fd)
        self.link = Path(link) if link else None
        if self.link is not None:
            self.link.parent.mkdir(parents=True, exist_ok=True)
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()
            self.link.symlink_to(self.pty_path)
        self.path = str(self.link or self.pty_path)
        self.is_open = False
        self.bitrate_code = "S8"
        self.rx_frames = 0
        self.tx_frames = 0
        self.bad_commands = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._notifier = can.Notifier(bus, [self], timeout=0.1)
        self._thread = threading.Thread(target=self._reader, name="slcan-device", daemon=True)
        self._thread.start()

    # bus -> host
    def on_message_received(self, msg: can.Message) -> None:
        if self.is_open:
            self._write(encode_frame(msg))
            self.tx_frames += 1

    def _write(self, data: bytes) -> None:
        with self._lock, contextlib.suppress(OSError):
            os.write(self.master_fd, data)

    # host -> bus
    def _reader(self) -> None:
        buf = b""
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.master_fd], [], [], 0.1)
                if not ready:
                    continue
                chunk = os.read(self.master_fd, 4096)
            except OSError:
                return
            buf += chunk
            while b"\r" in buf:
                line, buf = buf.split(b"\r", 1)
                self._command(line.decode("ascii", "replace").strip("\n"))

    def _command(self, line: str) -> None:
        if not line:
            self._write(OK)
            return
        c = line[0]
        if c in "tTrR":
            msg = decode_frame(line)
            if msg is None or not self.is_open:
                self.bad_commands += 1
                self._write(ERROR)
                return
            try:
                self.bus.send(msg)
            except can.CanError:
                self._write(ERROR)
                return
            self.rx_frames += 1
            self._write(b"z\r" if c in "tr" else b"Z\r")
        elif c in "OL":
            self.is_open = True
            self._write(OK)
        elif c == "C":
            self.is_open = False
            self._write(OK)
        elif c == "S" and len(line) == 2 and line[1] in "012345678":
            self.bitrate_code = line
            self._write(OK)
        elif c == "V":
            self._write(b"V1013\r")
        elif c == "v":
            self._write(b"v1013\r")
        elif c == "N":
            self._write(b"NCDCR\r")
        elif c == "F":
            self._write(b"F00\r")
        elif c in "Zs":
            self._write(OK)
        else:
            self.bad_commands += 1
            self._write(ERROR)

    def unplug(self) -> None:
        """Fault hook: the adapter disappears (pty closed; the host's reads and writes fail)."""
        self.stop()

    def stop(self) -> None:
        self._stop.set()
        self._notifier.stop(0.5)
        self._thread.join(1.0)
        for fd in (self.master_fd, self.slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()
