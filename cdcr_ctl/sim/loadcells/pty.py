"""The transport of the simulated transmitters: a pseudo-terminal (or a loopback TCP port:
:class:`TcpEndpoint`), the serving thread, fault hooks.

Fault hooks let tests and the simulated rig break the link on purpose: :meth:`PtySim.drop_next`,
:meth:`PtySim.corrupt_next` (bad CRC / unparsable line), :meth:`PtySim.inject_garbage`,
:meth:`PtySim.split_next` (a frame written in two pieces), :meth:`PtySim.garble_for` (nothing valid
for a while), :meth:`PtySim.disconnect` (the pty is closed, as if unplugged) /
:meth:`PtySim.reconnect`.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import math
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from cdcr_ctl.sensors.loadcell_modbus import char_time_s
from cdcr_ctl.sim.loadcells.feed import SensorNoise, SimStats, TensionFeed, Tensions
from cdcr_ctl.sim.loopback import listen_loopback

#: Line noise sent before every frame while :meth:`PtySim.garble_for` is in force.
GARBLE_NOISE = b"\x00\xff\x55\xaa#?\r"


class PtyEndpoint:
    """The device end of a pseudo-terminal: the simulator uses the master; clients open ``path``.

    The slave end is held open too (raw mode), so the master never sees a hang-up while no
    client is connected. ``link``: a symlink made to ``path`` (parents created), removed on close.
    Writes never block: bytes that do not fit (nobody reading) are dropped and counted.
    """

    def __init__(self, link: str | Path | None = None) -> None:
        self.master_fd, self.slave_fd = os.openpty()
        tty.setraw(self.slave_fd)
        flags = fcntl.fcntl(self.master_fd, fcntl.F_GETFL)
        fcntl.fcntl(self.master_fd, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self.path = os.ttyname(self.slave_fd)
        self.link = Path(link) if link is not None else None
        self.overflow_bytes = 0
        self._lock = threading.Lock()
        self.closed = False
        if self.link is not None:
            self.link.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self.path)
            tmp.replace(self.link)

    def write(self, data: bytes) -> None:
        """Send ``data`` to the client; what the pty buffer cannot take is dropped and counted."""
        with self._lock:
            if self.closed:
                return
            view = memoryview(data)
            while view:
                try:
                    n = os.write(self.master_fd, view)
                except BlockingIOError:
                    self.overflow_bytes += len(view)
                    return
                except OSError as exc:
                    if exc.errno == errno.EIO:  # no client and no keep-alive: nowhere to go
                        self.overflow_bytes += len(view)
                        return
                    raise
                view = view[n:]

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """Bytes the client sent (at most ``max_bytes``), waiting ``timeout_s`` (s); b'' if none."""
        if self.closed:
            return b""
        try:
            ready, _, _ = select.select([self.master_fd], [], [], timeout_s)
            if not ready:
                return b""
            return os.read(self.master_fd, max_bytes)
        except (BlockingIOError, InterruptedError):
            return b""
        except (OSError, ValueError):
            if self.closed:
                return b""
            raise

    def close(self) -> None:
        """Hang up: close both pty ends (the client's next read or write fails) and remove the
        symlink (idempotent).

        The master's descriptor number is not freed here but pointed at /dev/null (``dup2``
        closes the pty atomically), so a thread still blocked on it can never read a file
        opened later under the same number; :meth:`release` frees it.
        """
        with self._lock:
            if self.closed:
                return
            self.closed = True
            devnull = os.open(os.devnull, os.O_RDWR)
            try:
                os.dup2(devnull, self.master_fd)
            finally:
                os.close(devnull)
            with contextlib.suppress(OSError):
                os.close(self.slave_fd)
        if self.link is not None:
            with contextlib.suppress(OSError):
                if self.link.is_symlink() and os.readlink(self.link) == self.path:
                    self.link.unlink()

    def release(self) -> None:
        """Close the pty (if still open) and free the master's descriptor (idempotent).

        Call only when no thread uses this endpoint any more.
        """
        self.close()
        with self._lock:
            if self.master_fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(self.master_fd)
                self.master_fd = -1


class TcpEndpoint:
    """The device end on a loopback TCP port instead of a pty (a serial-to-Ethernet converter):
    clients open ``path``, ``socket://127.0.0.1:PORT`` (pyserial's URL). Why: a pty's bytes wait
    for the kernel's tty worker thread, which a loaded machine delays whatever the two ends'
    priority; loopback TCP hands them over in the writer's system call
    (:mod:`cdcr_ctl.sim.slcan_device`). One client at a time: :meth:`read` accepts it, and the
    next one once it hangs up. The interface is :class:`PtyEndpoint`'s; ``port`` 0: one the
    kernel picks. Writes never block: bytes with no client or no room are dropped and counted.
    """

    def __init__(self, port: int = 0) -> None:
        self._listener, self.path = listen_loopback(port)
        self.port = self._listener.getsockname()[1]
        self.link: Path | None = None
        self.overflow_bytes = 0
        self.closed = False
        self._conn: socket.socket | None = None
        self._lock = threading.Lock()

    def write(self, data: bytes) -> None:
        """Send ``data`` to the client; what cannot go now (no client, no room) is dropped."""
        with self._lock:
            conn = self._conn
            if self.closed or conn is None:
                self.overflow_bytes += len(data)
                return
            try:
                n = conn.send(data)
            except BlockingIOError:
                n = 0
            except OSError:
                self._hang_up()
                n = 0
            self.overflow_bytes += len(data) - n

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """Bytes the client sent (at most ``max_bytes``), waiting ``timeout_s`` (s); b'' if none
        (or while no client is connected: this accepts one)."""
        if self.closed:
            return b""
        conn = self._conn
        try:
            if conn is None:
                ready, _, _ = select.select([self._listener], [], [], timeout_s)
                if ready:
                    new, _ = self._listener.accept()
                    new.setblocking(False)
                    new.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    with self._lock:
                        self._conn = new
                return b""
            ready, _, _ = select.select([conn], [], [], timeout_s)
            if not ready:
                return b""
            data = conn.recv(max_bytes)
        except (BlockingIOError, InterruptedError):
            return b""
        except (OSError, ValueError):
            data = b""
        if not data:  # the client hung up: wait for the next
            with self._lock:
                self._hang_up()
        return data

    def _hang_up(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.close()

    def close(self) -> None:
        """Hang up and stop listening (idempotent): the client's next read or write fails."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            self._hang_up()
            with contextlib.suppress(OSError):
                self._listener.close()

    def release(self) -> None:
        self.close()


def endpoint(link: str | Path | None) -> PtyEndpoint | TcpEndpoint:
    """The device end for ``link``: a loopback TCP port for ``socket://127.0.0.1:PORT``, else a
    pty (symlinked to ``link`` when given)."""
    if link is not None and str(link).startswith("socket://"):
        host, _, port = str(link).removeprefix("socket://").rpartition(":")
        if host not in ("127.0.0.1", "localhost") or not port.isdigit():
            raise ValueError(f"{link}: a simulated port serves socket://127.0.0.1:PORT only")
        return TcpEndpoint(int(port))
    return PtyEndpoint(link)


@dataclass
class _Faults:
    drop: int = 0
    corrupt: int = 0
    split: int = 0
    split_gap_s: float = 0.005
    garbage: bytearray = field(default_factory=bytearray)
    garble_until_s: float = -math.inf


class PtySim:
    """Base of the simulated transmitters: pty, tension feed, fault hooks, serving thread."""

    def __init__(
        self,
        tensions: Tensions,
        n_cells: int,
        *,
        baudrate: int,
        emulate_baud: bool,
        noise: SensorNoise,
        link: str | Path | None,
        clock: Callable[[], float],
    ) -> None:
        self.baudrate = int(baudrate)
        self.char_s = char_time_s(self.baudrate)
        self.emulate_baud = emulate_baud
        self.clock = clock
        self.feed = TensionFeed(tensions, n_cells, noise, clock)
        self.stats = SimStats()
        self._faults = _Faults()
        self._faults_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.pty = endpoint(link)

    @property
    def path(self) -> str:
        """The pty the client opens (``/dev/pts/N``)."""
        return self.pty.path

    # -- fault hooks ----------------------------------------------------------------------

    def drop_next(self, n: int = 1) -> None:
        """Do not send the next ``n`` replies / lines."""
        with self._faults_lock:
            self._faults.drop += n

    def corrupt_next(self, n: int = 1) -> None:
        """Corrupt the next ``n`` replies (CRC) / lines (unit replaced by ``?``)."""
        with self._faults_lock:
            self._faults.corrupt += n

    def split_next(self, n: int = 1, gap_s: float = 0.005) -> None:
        """Write the next ``n`` frames in two pieces, ``gap_s`` (s) apart."""
        with self._faults_lock:
            self._faults.split += n
            self._faults.split_gap_s = gap_s

    def inject_garbage(self, data: bytes) -> None:
        """Send ``data`` just before the next frame (line noise, a stray device)."""
        with self._faults_lock:
            self._faults.garbage += data

    def garble_for(self, duration_s: float) -> None:
        """Fault hook: for ``duration_s`` (s) every reply / line is corrupted and preceded by
        line noise (a broken shield, a transmitter gone mad): no valid reading gets through."""
        with self._faults_lock:
            self._faults.garble_until_s = time.monotonic() + float(duration_s)

    def disconnect(self) -> None:
        """Close the pty: the client's next read or write fails, as if the cable were pulled."""
        self.pty.close()

    def reconnect(self) -> None:
        """Plug back in after :meth:`disconnect`: a new pty at the same link, served anew.
        (The client must open the port again.)"""
        if not self.pty.closed:
            return
        old = self.pty
        if self._thread is not None:
            self._thread.join(2.0)
        old.release()
        self.pty = TcpEndpoint(old.port) if isinstance(old, TcpEndpoint) else PtyEndpoint(old.link)
        self._thread = None
        if not self._stop.is_set():
            self.start()

    # -- life cycle -----------------------------------------------------------------------

    def start(self) -> PtySim:
        """Serve in a daemon thread (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(
                target=self.serve, name=f"{type(self).__name__} {self.path}", daemon=True
            )
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the pty."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
            if self._thread.is_alive():
                self.pty.close()  # hang up; the descriptor stays reserved for the thread
                return
        self.pty.release()

    def __enter__(self) -> PtySim:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def serve(self) -> None:
        """Serve until :meth:`stop` or :meth:`disconnect` (blocking)."""
        raise NotImplementedError

    # -- sending a frame through the fault hooks --------------------------------------------

    def _send(self, frame: bytes, corrupt: Callable[[bytes], bytes]) -> None:
        with self._faults_lock:
            f = self._faults
            if f.drop:
                f.drop -= 1
                self.stats.dropped += 1
                return
            garbling = time.monotonic() < f.garble_until_s
            if f.corrupt or garbling:
                if not garbling:
                    f.corrupt -= 1
                else:
                    f.garbage += GARBLE_NOISE
                frame = corrupt(frame)
                self.stats.corrupted += 1
            garbage, f.garbage = bytes(f.garbage), bytearray()
            split = f.split > 0
            if split:
                f.split -= 1
            gap_s = f.split_gap_s
        data = garbage + frame
        if split:
            cut = len(garbage) + max(1, len(frame) // 2)
            self.pty.write(data[:cut])
            time.sleep(gap_s)
            self.pty.write(data[cut:])
        else:
            self.pty.write(data)
        self.stats.replies += 1
        self.stats.overflow_bytes = self.pty.overflow_bytes
