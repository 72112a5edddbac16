"""Benchmark: the slcan frame path at 1 kHz, python-can's ``slcanBus`` against ``SlcanBus``.

What runs: a pseudo-terminal pair; on the master side a helper process plays the USB-CAN adapter
(per burst ending with SYNC it answers four ``z`` acknowledgements and three TPDO lines, in one
write, as the simulated adapter does); on the slave side the bus under test sends a cycle's burst
(3 RPDOs + SYNC) every millisecond from the main thread while a second thread receives. Printed
per bus: frames received, the receiving thread's CPU time per cycle (``time.thread_time``), the
sending thread's CPU time per cycle (pacing included) and the wall time of sending one burst
(``time.perf_counter``; python-can drains the port after every frame: it waits for the reader).

    .venv/bin/python benchmarks/bench_slcan.py [--cycles 3000]
"""

from __future__ import annotations

import argparse
import os
import select
import subprocess
import sys
import threading
import time
import tty

import can
import numpy as np
from can.interfaces.slcan import slcanBus

from cdcr_ctl.drives.slcan import SlcanBus

ANSWER = b"z\r" * 4 + b"".join(b"t18%d63716E8030000\r" % n for n in (1, 2, 3))


def adapter(fd: int) -> None:
    """The helper process: answer every burst (it ends with SYNC ``t0800``) until ``Q``."""
    os.set_blocking(fd, False)
    buf = b""
    while True:
        select.select([fd], [], [])
        try:
            data = os.read(fd, 4096)
        except BlockingIOError:
            continue
        if not data:
            return
        buf += data
        while b"t0800\r" in buf:
            _, buf = buf.split(b"t0800\r", 1)
            os.write(fd, ANSWER)
        if b"Q" in buf:
            return


def run(cls: type, name: str, cycles: int) -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    helper = subprocess.Popen(
        [sys.executable, __file__, "--adapter", str(master)], pass_fds=(master,)
    )
    bus = cls(channel=os.ttyname(slave), bitrate=1_000_000, sleep_after_open=0)
    received = 0
    rx_cpu = 0.0
    stop = threading.Event()

    def receive() -> None:
        nonlocal received, rx_cpu
        c0 = time.thread_time()
        while not stop.is_set():
            if bus.recv(0.05) is not None:
                received += 1
        rx_cpu = time.thread_time() - c0

    rx = threading.Thread(target=receive)
    rx.start()
    frames = [(0x200 + n, b"\x01\x02\x03\x04") for n in (1, 2, 3)] + [(0x080, b"")]
    burst = [can.Message(arbitration_id=i, data=d, is_extended_id=False) for i, d in frames]
    send_wall = np.zeros(cycles)
    c0 = time.thread_time()
    t0 = time.monotonic()
    try:
        for k in range(cycles):
            deadline = t0 + k * 0.001
            while (left := deadline - time.monotonic()) > 0:
                time.sleep(left)
            w0 = time.perf_counter()
            if isinstance(bus, SlcanBus):
                bus.send_frames(frames, 0.005)
            else:
                for m in burst:
                    bus.send(m)
            send_wall[k] = time.perf_counter() - w0
        tx_cpu = time.thread_time() - c0
        time.sleep(0.3)
    finally:
        stop.set()
        rx.join()
        os.write(slave, b"Q\r")
        bus.shutdown()
        helper.wait(5)
        os.close(slave)
        os.close(master)
    us = send_wall * 1e6
    print(
        f"{name}: frames received {received}/{3 * cycles}; receiving thread CPU "
        f"{rx_cpu / cycles * 1e6:.0f} us per cycle; sending thread CPU "
        f"{tx_cpu / cycles * 1e6:.0f} us per cycle (pacing included); one burst sent in "
        f"p50 {np.percentile(us, 50):.0f}, p99 {np.percentile(us, 99):.0f}, "
        f"max {us.max():.0f} us (wall)"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=3000)
    ap.add_argument("--adapter", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.adapter is not None:
        adapter(args.adapter)
        return
    for cls, name in ((slcanBus, "python-can slcanBus"), (SlcanBus, "SlcanBus")):
        run(cls, name, args.cycles)


if __name__ == "__main__":
    main()
