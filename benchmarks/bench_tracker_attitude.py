"""Tracker and attitude-sensor timing: decode cost, loopback/pty delivery latency, latest() cost.

What is measured, and how:

1. NatNet over loopback. The simulated server runs in its own process
   (``python -m cdcr_ctl.sim.tracker``) at ``--rate-hz``; the production client
   (:func:`cdcr_ctl.sensors.tracker.open_tracker`) reads it for ``--duration-s``. The server
   stamps each frame's transmit time with ``time.monotonic()`` (CLOCK_MONOTONIC, shared by all
   processes on the machine) in 0.1 us ticks; the client's receive time minus that stamp is the
   delivery latency (socket + wake-up + decode, until the sample is published). Also counted:
   frames received vs. sent at the nominal rate.
2. NatNet decode cost in-process: ``parse_frame_of_data`` and ``handle_datagram`` on a NatNet 4.1
   frame with one rigid body, two marker sets and three labeled markers (what Motive sends for a
   one-body scene), timed over many calls with ``time.perf_counter``.
3. WitMotion over a pty: this process writes a 4-frame cycle (acc, gyro, angle, quaternion =
   44 bytes) to the pty master every 5 ms, recording ``time.monotonic()`` just before each
   write; the reader thread publishes the angle with its own receive time. Latency = published
   time - write time. A pty has no baud-rate timing: on a real 115200 bit/s link add
   44 * 10 / 115200 = 3.8 ms of transmission for the cycle (9600 bit/s: 46 ms).
4. WitMotion decode throughput (bytes/s) in-process.
5. ``latest()`` cost for the tracker and a sensor: what the control loop pays per cycle.

Usage::

    .venv/bin/python benchmarks/bench_tracker_attitude.py [--duration-s 3] [--rate-hz 240]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
import tty
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import serial  # noqa: E402

from cdcr_ctl.config.tracking import TrackerConfig  # noqa: E402
from cdcr_ctl.sensors.attitude import (  # noqa: E402
    WitMotionDecoder,
    WitMotionSensor,
    pack_acceleration,
    pack_angle,
    pack_angular_rate,
    pack_quaternion,
)
from cdcr_ctl.sensors.natnet import (  # noqa: E402
    FrameOfData,
    LabeledMarker,
    MarkerSet,
    NatNetVersion,
    RigidBodyPose,
    ServerInfo,
    pack_frame_of_data,
    pack_server_info,
    parse_frame_of_data,
    split_message,
)
from cdcr_ctl.sensors.tracker import NatNetTracker, TrackerTransform, open_tracker  # noqa: E402
from cdcr_ctl.sim.tracker import SIM_CLOCK_HZ  # noqa: E402


def percentiles(values_s: list[float]) -> str:
    v = sorted(values_s)
    if not v:
        return "no samples"
    p = lambda q: v[min(len(v) - 1, int(q * len(v)))] * 1e3  # noqa: E731
    return f"median {p(0.5):.3f} ms, p99 {p(0.99):.3f} ms, max {v[-1] * 1e3:.3f} ms (n={len(v)})"


def per_call_us(fn, n: int) -> float:  # type: ignore[no-untyped-def]
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t) / n * 1e6


def bench_natnet_loopback(duration_s: float, rate_hz: float) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "cdcr_ctl.sim.tracker", "--rate-hz", str(rate_hz)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        command_port = int(proc.stdout.readline().split()[0])  # type: ignore[union-attr]
        cfg = TrackerConfig(host="127.0.0.1", command_port=command_port, stale_after_s=1.0)
        reader = open_tracker(cfg, start=False)
        assert isinstance(reader, NatNetTracker)
        latencies: list[float] = []
        original = reader.handle_datagram

        def timed(data: bytes, source=None, t_rx=None) -> None:  # type: ignore[no-untyped-def]
            before = reader.stats.samples
            original(data, source, t_rx)
            if reader.stats.samples > before:
                published = time.monotonic()
                frame = parse_frame_of_data(split_message(data)[1], reader.version)
                latencies.append(published - frame.stamp_transmit / SIM_CLOCK_HZ)

        reader.handle_datagram = timed  # type: ignore[method-assign]
        with reader:
            time.sleep(0.3)  # settle
            latencies.clear()
            n0 = reader.stats.samples
            time.sleep(duration_s)
            n = reader.stats.samples - n0
        print(f"NatNet loopback at {rate_hz:.0f} Hz for {duration_s:.1f} s (server: own process):")
        print(
            f"  frames published: {n} of ~{rate_hz * duration_s:.0f} sent ({n / duration_s:.1f} /s)"
        )
        print(f"  bad {reader.stats.bad}, out of order {reader.stats.out_of_order}")
        print(f"  delivery latency (send -> published): {percentiles(latencies)}")
    finally:
        proc.terminate()
        proc.wait(5)


def bench_natnet_decode() -> None:
    body = RigidBodyPose(1, (0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 1.0), 0.0002, True)
    pts = ((0.11, 0.2, 0.3), (0.1, 0.21, 0.3), (0.1, 0.2, 0.31))
    frame = FrameOfData(
        1,
        (body,),
        1.0,
        marker_sets=(MarkerSet("tip", pts), MarkerSet("all", pts)),
        labeled_markers=tuple(LabeledMarker(65537 + i, p, 0.008) for i, p in enumerate(pts)),
    )
    v = NatNetVersion(4, 1)
    data = pack_frame_of_data(frame, v)
    payload = split_message(data)[1]
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        tr = NatNetTracker(s, ("127.0.0.1", 1510), TrackerTransform.identity(1000.0), 1)
        tr.handle_datagram(
            pack_server_info(ServerInfo("x", (3, 1, 0, 0), v, 10**7, 1511, False, "0.0.0.0"))
        )
        counter = iter(range(2, 10**9))

        def one() -> None:
            tr.handle_datagram(pack_frame_of_data(replace(frame, frame_number=next(counter)), v))

        pack_us = per_call_us(lambda: pack_frame_of_data(replace(frame, frame_number=2), v), 5000)
        print(f"NatNet 4.1 decode ({len(data)}-byte frame, 1 body, 2 marker sets, 3 labeled):")
        parse_us = per_call_us(lambda: parse_frame_of_data(payload, v), 20000)
        handle_us = per_call_us(one, 5000) - pack_us
        print(f"  parse_frame_of_data: {parse_us:.1f} us")
        print(f"  handle_datagram (parse + transform + publish): {handle_us:.1f} us")
        print(f"  latest(): {per_call_us(tr.latest, 50000):.2f} us")


def bench_witmotion_pty(duration_s: float) -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    port = serial.Serial(os.ttyname(slave), 115200)
    sensor = WitMotionSensor(port)
    written: dict[int, float] = {}
    latencies: list[float] = []
    original = sensor.handle_bytes

    def timed(data: bytes, t_rx=None) -> int:  # type: ignore[no-untyped-def]
        made = original(data, t_rx)
        if made:
            stamped = sensor.values.stamped
            assert stamped is not None
            seq_sent = round(stamped.value.roll_rad * 1e4)  # the cycle number rides in roll
            if seq_sent in written:
                latencies.append(stamped.t_s - written.pop(seq_sent))
        return made

    sensor.handle_bytes = timed  # type: ignore[method-assign]
    stop = threading.Event()
    with sensor:
        k = 0
        t_end = time.monotonic() + duration_s
        while time.monotonic() < t_end:
            k = k % 500 + 1
            roll_deg = np.degrees(k * 1e-4)
            cycle = (
                pack_acceleration((0, 0, 1))
                + pack_angular_rate((0, 0, 0))
                + pack_angle(roll_deg, 0, 0)
                + pack_quaternion((1, 0, 0, 0))
            )
            written[k] = time.monotonic()
            os.write(master, cycle)
            time.sleep(0.005)
        time.sleep(0.05)
    stop.set()
    os.close(master)
    os.close(slave)
    print(f"WitMotion over a pty, 44-byte cycle every 5 ms for {duration_s:.1f} s:")
    print(f"  write -> published: {percentiles(latencies)}")
    latest_us = per_call_us(sensor.latest, 50000)
    print(f"  bad frames {sensor.stats.bad_frames}; latest(): {latest_us:.2f} us")


def bench_witmotion_decode() -> None:
    cycle = (
        pack_acceleration((0, 0, 1))
        + pack_angular_rate((0, 0, 0))
        + pack_angle(1, 2, 3)
        + pack_quaternion((1, 0, 0, 0))
    )
    blob = cycle * 2000
    dec = WitMotionDecoder()
    t = time.perf_counter()
    n = len(dec.feed(blob))
    dt = time.perf_counter() - t
    print(f"WitMotion decode: {len(blob) / dt / 1e6:.2f} MB/s ({n / dt / 1e3:.0f} k frames/s)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=3.0)
    ap.add_argument("--rate-hz", type=float, default=240.0)
    args = ap.parse_args(argv)
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs")
    bench_natnet_decode()
    bench_witmotion_decode()
    bench_natnet_loopback(args.duration_s, args.rate_hz)
    bench_witmotion_pty(args.duration_s)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
