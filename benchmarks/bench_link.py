"""Delivery latency of the links between the simulated rig and the daemon: a raw pty (how
``cdcr-ctl sim`` serves its slcan adapter by default) against loopback TCP
(``can.channel: socket://127.0.0.1:PORT``), both ends at SCHED_FIFO.

One thread writes an 8-byte monotonic time stamp every ``--period-ms`` (4 ms: a 250 Hz cycle)
into the link; a second thread of the same process reads it from the other end and records
now - stamp. Both run at SCHED_FIFO ``--priority`` (60, the tests' stand-in hardware) when
permitted. The two links are measured one after the other, ``--seconds`` each; run it beside
the load you care about (``stress-ng --cpu 2``) to see what a loaded machine does to each.

Why they differ: bytes written to a pty reach the reader through the kernel's tty flip-buffer
worker, a time-shared kernel thread that neither end's priority lifts; loopback TCP hands
them over in the writer's own system call. Prints per link: messages, p50 / p99 / p99.9 / max
(ms), and how many took over 50 and 100 ms. Usage::

    .venv/bin/python benchmarks/bench_link.py [--seconds 60] [--period-ms 4] [--priority 60]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import socket
import struct
import threading
import time
import tty
from collections.abc import Callable

STAMP = struct.Struct("<d")


def _pty() -> tuple[Callable[[bytes], object], Callable[[], bytes], Callable[[], None]]:
    master, slave = os.openpty()
    tty.setraw(slave)

    def close() -> None:
        os.close(master)
        os.close(slave)

    return (lambda b: os.write(master, b)), (lambda: os.read(slave, 4096)), close


def _tcp() -> tuple[Callable[[bytes], object], Callable[[], bytes], Callable[[], None]]:
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(1)
        tx = socket.create_connection(listener.getsockname())
        rx, _ = listener.accept()
    tx.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def close() -> None:
        tx.close()
        rx.close()

    return tx.sendall, (lambda: rx.recv(4096)), close


def measure(kind: str, seconds: float, period_s: float) -> list[float]:
    """Latencies (s) of one link, ``seconds`` of stamps every ``period_s``."""
    write, read, close = _pty() if kind == "pty" else _tcp()
    lat: list[float] = []
    done = threading.Event()

    def reader() -> None:
        buf = b""
        while not done.is_set():
            try:
                buf += read()
            except OSError:
                return
            while len(buf) >= STAMP.size:
                (t,) = STAMP.unpack_from(buf)
                buf = buf[STAMP.size :]
                lat.append(time.monotonic() - t)

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        write(STAMP.pack(time.monotonic()))
        time.sleep(period_s)
    time.sleep(0.2)  # the last stamps arrive
    done.set()
    close()
    return sorted(lat)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--period-ms", type=float, default=4.0)
    ap.add_argument("--priority", type=int, default=60, help="SCHED_FIFO priority; 0: none")
    args = ap.parse_args()
    policy = "SCHED_OTHER"
    if args.priority:
        with contextlib.suppress(PermissionError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.priority))
            policy = f"SCHED_FIFO {args.priority}"
    print(
        f"link latency: {args.seconds:.0f} s per link, a stamp every {args.period_ms} ms, "
        f"both ends {policy}, load average {os.getloadavg()[0]:.1f}"
    )
    for kind in ("pty", "tcp"):
        lat = measure(kind, args.seconds, args.period_ms / 1e3)
        n = len(lat)
        ms = [lat[min(n - 1, int(q * n))] * 1e3 for q in (0.5, 0.99, 0.999)]
        print(
            f"{kind:3s}: {n} messages, p50 {ms[0]:.3f} ms, p99 {ms[1]:.3f} ms, "
            f"p99.9 {ms[2]:.3f} ms, max {lat[-1] * 1e3:.1f} ms; "
            f"over 50 ms: {sum(x > 0.05 for x in lat)}, over 100 ms: {sum(x > 0.1 for x in lat)}"
        )


if __name__ == "__main__":
    main()
