"""A simulated USB-CAN adapter: the Lawicel/slcan ASCII protocol on a pseudo-terminal.

The simulated rig owns the pty's master side and a python-can bus (usually ``virtual``) holding
the simulated nodes; a controller in another process opens the pty's slave side with python-can's
``slcan`` interface, exactly as it would open a real adapter (``/dev/ttyACM0``).

``tcp=True`` serves the same protocol on a loopback TCP port instead (a networked slcan adapter,
as ser2net or a WiFi CAN bridge offers it): the controller opens ``socket://127.0.0.1:PORT``
(pyserial's URL, which python-can's slcan accepts as channel). Why: bytes written to a pty reach
the other side through a kernel worker thread (the tty flip buffer), an ordinary time-shared
thread that a busy machine can leave waiting for tens of milliseconds; loopback TCP hands them
over in the writer's own system call. ``tcp_port``: that port (0: one the kernel picks). One
host at a time; when it disconnects the next may.

Host -> adapter, one command per ``\\r`` (``\\n`` ignored). Answers are ``\\r`` (OK) or ``\\a``
(BEL, error), as Lawicel's CANUSB does:

=============  ==========================================================================
``Sn``         bit rate n = 0-8 (10k, 20k, 50k, 100k, 125k, 250k, 500k, 800k, 1M); closed only
``sxxyy``      BTR0/BTR1 bit timing; closed only (taken to match the bus)
``O`` / ``L``  open the channel (``L`` listen-only: no transmission); BEL when already open
``C``          close the channel; BEL when not open
``tiiildd..``  transmit a standard frame (``T`` extended, ``r``/``R`` remote); answer ``z\\r`` /
               ``Z\\r``; BEL when closed, listen-only or malformed
``V`` ``v``    hardware/firmware version ``V1013\\r``; ``N`` serial number ``NCDCR\\r``
``F``          status flags ``Fxx\\r`` (bit 0 RX FIFO full, 3 data overrun, 5 error passive, 7 bus
               error), cleared by reading; open only
``Z0`` ``Z1``  frame timestamps off/on (4 hex digits, ms modulo 60000); closed only
``Mxxxxxxxx``  acceptance code / ``m`` mask: accepted (all frames pass); closed only
=============  ==========================================================================

An empty command (python-can sends one after ``Sn``) is OK. Adapter -> host: every frame on the
bus as a ``t``/``T``/``r``/``R`` line, while the channel is open. If the host's bit rate differs
from the bus's, nothing passes either way and ``F`` reports bus error + error passive, as a
real adapter on a wrong-rate bus would. Writes to the pty never block the bus: when the host does
not read, frames are dropped and ``F`` reports a data overrun.

As a USB adapter does, the device answers every command of one read from the host in one write
(a cycle's set-points and SYNC: four ``z``). Two ways to the bus: a python-can ``bus`` (the
answers go out, then the frames to the bus; a listener thread relays the bus's frames to the
host), or ``deliver`` (the nodes' dispatcher, called in the reader thread; the nodes' frames come
back through :meth:`SlcanDevice.on_message_received`, and those they send while a read is being
delivered, the TPDOs a SYNC triggers, go to the host in the same write, after the answers: one
USB transfer, one wake-up of the host's reader).
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path

import can

from cdcr_ctl.sim.loopback import listen_loopback

log = logging.getLogger(__name__)

OK, ERROR = b"\r", b"\a"
#: Lawicel S-codes and their bit rates.
BITRATE_CODES = {
    "S0": 10_000,
    "S1": 20_000,
    "S2": 50_000,
    "S3": 100_000,
    "S4": 125_000,
    "S5": 250_000,
    "S6": 500_000,
    "S7": 800_000,
    "S8": 1_000_000,
}
VERSION, FIRMWARE, SERIAL = b"V1013\r", b"v1013\r", b"NCDCR\r"
# F status flag bits
F_RX_FIFO_FULL, F_TX_FIFO_FULL, F_ERROR_WARNING, F_DATA_OVERRUN = 0x01, 0x02, 0x04, 0x08
F_ERROR_PASSIVE, F_ARBITRATION_LOST, F_BUS_ERROR = 0x20, 0x40, 0x80
#: A command line longer than this without ``\\r`` is junk: dropped with a BEL.
MAX_LINE = 64
#: How long the rest of a line already partly written may wait for the host (s).
PARTIAL_LINE_S = 1.0
#: How long a write to the pty may wait for the host to read before frames are dropped (s).
WRITE_STALL_S = 0.02


def encode_frame(msg: can.Message, timestamp_ms: int | None = None) -> bytes:
    """One slcan line for ``msg`` (with a 4-hex-digit timestamp when given)."""
    if msg.is_extended_id:
        head = f"{'R' if msg.is_remote_frame else 'T'}{msg.arbitration_id:08X}{msg.dlc}"
    else:
        head = f"{'r' if msg.is_remote_frame else 't'}{msg.arbitration_id:03X}{msg.dlc}"
    body = "" if msg.is_remote_frame else bytes(msg.data).hex().upper()
    stamp = "" if timestamp_ms is None else f"{timestamp_ms % 60000:04X}"
    return (head + body + stamp).encode() + b"\r"


def decode_frame(line: str) -> can.Message | None:
    """One slcan frame command (``t``, ``T``, ``r``, ``R``; no ``\\r``) -> Message; None if bad."""
    if not line or line[0] not in "tTrR":
        return None
    ext = line[0] in "TR"
    remote = line[0] in "rR"
    id_len = 8 if ext else 3
    head = line[1 : 1 + id_len]
    if len(head) != id_len or len(line) < 2 + id_len:
        return None
    try:
        can_id = int(head, 16)
        dlc = int(line[1 + id_len], 16)
    except ValueError:
        return None
    if dlc > 8 or can_id > (0x1FFFFFFF if ext else 0x7FF):
        return None
    body = line[2 + id_len :]
    if remote:
        if body:
            return None
        data = b""
    else:
        if len(body) != 2 * dlc:
            return None
        try:
            data = bytes.fromhex(body)
        except ValueError:
            return None
    return can.Message(
        arbitration_id=can_id, is_extended_id=ext, is_remote_frame=remote, dlc=dlc, data=data
    )


class _BusTap(can.Listener):
    def __init__(self, device: SlcanDevice) -> None:
        self._device = device

    def on_message_received(self, msg: can.Message) -> None:
        self._device.on_message_received(msg)

    def stop(self) -> None:
        pass


class SlcanDevice:
    """The adapter: pty master <-> ``bus``. ``path`` is the slave side (or ``link`` to it).

    ``bitrate`` is the bus's bit rate (the host must choose the same with ``Sn``); the adapter
    starts configured for it, as if the host had set it before. With ``deliver`` (and ``bus``
    None) the host's frames go to ``deliver`` instead of a bus, and the owner passes the bus's
    frames to :meth:`on_message_received` itself.
    """

    def __init__(
        self,
        bus: can.BusABC | None,
        link: str | Path | None = None,
        bitrate: int = 1_000_000,
        *,
        deliver: Callable[[can.Message], None] | None = None,
        tcp: bool = False,
        tcp_port: int = 0,
    ) -> None:
        if (bus is None) == (deliver is None):
            raise ValueError("give a bus or a deliver function (one of them)")
        if tcp and link:
            raise ValueError("a TCP adapter has an address, not a pty to link to")
        self.bus = bus
        self._deliver = deliver
        self.bus_bitrate = bitrate
        self.link = Path(link) if link else None
        self._listener: socket.socket | None = None
        self._conn: socket.socket | None = None
        if tcp:
            self.master_fd, self.slave_fd = -1, -1  # -1: no host connected
            self._listener, self.path = listen_loopback(tcp_port)
            self.pty_path = ""
        else:
            self.master_fd, self.slave_fd = os.openpty()
            tty.setraw(self.slave_fd)
            os.set_blocking(self.master_fd, False)
            self.pty_path = os.ttyname(self.slave_fd)
            if self.link is not None:
                self.link.parent.mkdir(parents=True, exist_ok=True)
                with contextlib.suppress(FileNotFoundError):
                    self.link.unlink()
                self.link.symlink_to(self.pty_path)
            self.path = str(self.link or self.pty_path)
        self.is_open = False
        self.listen_only = False
        self.timestamps = False
        self.bitrate: int | None = bitrate
        self.flags = 0
        self.rx_frames = 0  # host -> bus
        self.tx_frames = 0  # bus -> host
        self.dropped_frames = 0
        self.bad_commands = 0
        self._t0 = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        #: Lines for the host gathered while the reader delivers one read (reader thread only).
        self._batch: list[bytes] | None = None
        self._notifier = (
            can.Notifier(bus, [_BusTap(self)], timeout=0.1) if bus is not None else None
        )
        self._thread = threading.Thread(target=self._reader, name="slcan-device", daemon=True)
        self._thread.start()

    @property
    def rate_matches(self) -> bool:
        return self.bitrate is None or self.bitrate == self.bus_bitrate

    # ------------------------------------------------------------------ bus -> host
    def on_message_received(self, msg: can.Message) -> None:
        if not self.is_open or msg.is_error_frame:
            return
        if not self.rate_matches:
            self.flags |= F_BUS_ERROR | F_ERROR_PASSIVE
            return
        stamp = int((time.monotonic() - self._t0) * 1000) if self.timestamps else None
        line = encode_frame(msg, stamp)
        batch = self._batch
        if batch is not None and threading.current_thread() is self._thread:
            batch.append(line)  # an answer to what the reader is delivering: one write
            return
        self._count_write(self._write(line), 1)

    def _count_write(self, ok: bool, frames: int) -> None:
        if ok:
            self.tx_frames += frames
        else:
            self.dropped_frames += frames
            self.flags |= F_DATA_OVERRUN | F_RX_FIFO_FULL

    def _write(self, data: bytes) -> bool:
        """Write all of ``data`` to the host, waiting at most WRITE_STALL_S for it to read."""
        deadline = time.monotonic() + WRITE_STALL_S
        whole = len(data)
        with self._lock:
            if self.master_fd < 0:
                return False  # TCP: no host connected
            while data:
                try:
                    n = os.write(self.master_fd, data)
                    data = data[n:]
                except BlockingIOError:
                    left = deadline - time.monotonic()
                    if left <= 0 and len(data) == whole:
                        return False  # dropped whole, as an adapter's full FIFO drops frames
                    if left <= 0:
                        # Part of the line is out: finish it (within one more second), or the
                        # host would read two frames run together as one garbled line.
                        left = deadline + PARTIAL_LINE_S - time.monotonic()
                        if left <= 0:
                            return False
                    with contextlib.suppress(OSError, ValueError):
                        select.select([], [self.master_fd], [], left)
                except OSError:
                    return False
        return True

    # ------------------------------------------------------------------ host -> bus
    def _accept(self) -> bool:
        """TCP: wait (briefly) for a host to connect; True when one is connected."""
        assert self._listener is not None
        ready, _, _ = select.select([self._listener], [], [], 0.1)
        if not ready:
            return False
        conn, _ = self._listener.accept()
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # a line is a packet
        with self._lock:
            self._conn, self.master_fd = conn, conn.fileno()
        return True

    def _hang_up(self) -> None:
        """TCP: the host went away; wait for the next one (the adapter keeps its settings)."""
        with self._lock:
            conn, self._conn, self.master_fd = self._conn, None, -1
        if conn is not None:
            conn.close()

    def _reader(self) -> None:
        buf = b""
        while not self._stop.is_set():
            try:
                if self.master_fd < 0:
                    if self._listener is None or not self._accept():
                        continue
                    buf = b""
                ready, _, _ = select.select([self.master_fd], [], [], 0.1)
                if not ready:
                    continue
                chunk = os.read(self.master_fd, 4096)
            except BlockingIOError:
                continue
            except (OSError, ValueError):
                if self._listener is not None and not self._stop.is_set():
                    self._hang_up()
                    continue
                return
            if not chunk and self._listener is not None:
                self._hang_up()
                continue
            buf += chunk.replace(b"\n", b"")
            answers: list[bytes] = []
            frames: list[can.Message] = []
            while b"\r" in buf:
                line, buf = buf.split(b"\r", 1)
                answer, msg = self._command(line.decode("ascii", "replace"))
                answers.append(answer)
                if msg is not None:
                    frames.append(msg)
            if len(buf) > MAX_LINE:
                buf = b""
                self.bad_commands += 1
                answers.append(ERROR)
            if frames and self._deliver is not None:
                self._put_on_bus(frames, answers)
                continue
            if answers:
                self._write(b"".join(answers))
            if frames:
                self._put_on_bus(frames)

    def _put_on_bus(self, frames: list[can.Message], answers: list[bytes] | None = None) -> None:
        """Frames the host sent (acknowledged in ``answers``, or already) onto the bus, in
        order. With ``deliver``, the answers and what the nodes send meanwhile (the TPDOs a
        SYNC triggers) go to the host in one write, answers first."""
        if self._deliver is None:
            for msg in frames:
                self._send(msg)
            return
        self._batch = []
        try:
            stamp = time.time()
            for msg in frames:
                msg.timestamp = stamp
                self._deliver(msg)
                self.rx_frames += 1
        finally:
            batch, self._batch = self._batch, None
        head = b"".join(answers) if answers else b""
        if batch or head:
            ok = self._write(head + b"".join(batch))
            if batch:
                self._count_write(ok, len(batch))

    def _send(self, msg: can.Message) -> None:
        assert self.bus is not None
        try:
            self.bus.send(msg)
        except can.CanError:
            self.flags |= F_BUS_ERROR  # acknowledged into the FIFO, lost on the bus
            return
        self.rx_frames += 1

    def command(self, line: str) -> bytes:
        """Execute one command line (without ``\\r``); the bytes to answer. A frame goes onto
        the bus at once."""
        answer, msg = self._command(line)
        if msg is not None:
            self._put_on_bus([msg])
        return answer

    def _command(self, line: str) -> tuple[bytes, can.Message | None]:
        """The answer to one command line, and the frame to put on the bus (or None)."""
        if line[:1] in ("t", "T", "r", "R"):
            return self._transmit(line)
        return self._control(line), None

    def _control(self, line: str) -> bytes:
        if not line:
            return OK
        c = line[0]
        if c in "OL" and len(line) == 1:
            if self.is_open:
                return self._bad()
            self.is_open, self.listen_only = True, c == "L"
            return OK
        if c == "C" and len(line) == 1:
            if not self.is_open:
                return self._bad()
            self.is_open = False
            return OK
        if c == "S" and line in BITRATE_CODES and not self.is_open:
            self.bitrate = BITRATE_CODES[line]
            return OK
        if c == "s" and len(line) == 5 and not self.is_open and _is_hex(line[1:]):
            self.bitrate = None
            return OK
        if line == "V":
            return VERSION
        if line == "v":
            return FIRMWARE
        if line == "N":
            return SERIAL
        if line == "F" and self.is_open:
            flags, self.flags = self.flags, 0
            return f"F{flags:02X}\r".encode()
        if line in ("Z0", "Z1") and not self.is_open:
            self.timestamps = line == "Z1"
            return OK
        if c in "Mm" and len(line) == 9 and _is_hex(line[1:]) and not self.is_open:
            return OK
        return self._bad()

    def _bad(self) -> bytes:
        self.bad_commands += 1
        return ERROR

    def _transmit(self, line: str) -> tuple[bytes, can.Message | None]:
        msg = decode_frame(line)
        if msg is None or not self.is_open or self.listen_only:
            return self._bad(), None
        ack = b"z\r" if line[0] in "tr" else b"Z\r"
        if not self.rate_matches:
            self.flags |= F_BUS_ERROR | F_ERROR_PASSIVE
            return ack, None  # accepted into the FIFO; it never gets onto a bus at another rate
        return ack, msg

    # ------------------------------------------------------------------ lifecycle
    def unplug(self) -> None:
        """Fault hook: the adapter disappears (pty closed; the host's reads and writes fail)."""
        self.stop()

    def stop(self) -> None:
        """Close the adapter: stop relaying, close the pty (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._notifier is not None:
            self._notifier.stop(0.5)
        self._thread.join(1.0)
        if self._listener is not None:
            self._hang_up()
            self._listener.close()
            return
        for fd in (self.master_fd, self.slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()


def _is_hex(text: str) -> bool:
    try:
        int(text, 16)
    except ValueError:
        return False
    return True
