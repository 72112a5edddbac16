"""Issue #21's battery: hostile and unlucky requests while a trajectory runs, ``stop`` in the
middle of each, and what the loop says about it. Used by ``tests/system/test_stop_battery.py``
(light) and ``benchmarks/bench_stop_battery.py`` (full, prints the histograms).

Each stressor runs in a thread while a trajectory runs on the simulated rig; in its middle a
``stop`` is sent. The stop's reply carries the loop cycle that acted on it and how many cycles
after the request that was (``cycles_waited``); the loop's counters (long cycles, missed
deadlines, lateness) are read from ``status`` before and after.
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from syshelp import client

from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon.client import DaemonError


def _raw(work: Path, data: bytes, chunk: int = 1 << 20, pause_s: float = 0.0) -> str:
    """Send ``data`` on a fresh connection (in chunks, pausing between) and return the reply."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(120)
    s.connect(str(work / "control.sock"))
    try:
        for i in range(0, len(data), chunk):
            s.sendall(data[i : i + chunk])
            if pause_s:
                time.sleep(pause_s)
        buf = b""
        while b"\n" not in buf:
            part = s.recv(65536)
            if not part:
                break
            buf += part
        return buf.decode(errors="replace")
    finally:
        s.close()


def idle(seconds: float) -> Callable[[Path], str]:
    """No stressor: the loop's counters under the machine's own load, for comparison."""

    def send(work: Path) -> str:
        time.sleep(seconds)
        return "idle"

    return send


def big_request(n_bytes: int) -> Callable[[Path], str]:
    def send(work: Path) -> str:
        pad = b"0.0, " * (n_bytes // 5)
        line = b'{"cmd": "trajectory", "args": {"name": "big", "samples": [[' + pad + b"0]]}}\n"
        return _raw(work, line)

    return send


def file_trajectory(rows: int, tmp: Path) -> Callable[[Path], str]:
    """A ``rows``-row CSV trajectory (written now) sent as a file: read, parsed and validated in
    the daemon's intake process while the current run goes on."""
    t = np.arange(rows) * 1e-3
    theta = 0.3 * (1 - np.cos(2 * np.pi * t / max(t[-1], 1.0))) / 2
    path = tmp / f"traj{rows}.csv"
    np.savetxt(
        path,
        np.column_stack((t, theta, np.zeros(rows))),
        delimiter=",",
        header="t_s,seg1_theta_rad,seg1_phi_rad",
        comments="",
        fmt="%.6f",
    )

    def send(work: Path) -> str:
        try:
            with client(work) as c:
                return json.dumps(
                    c.call("trajectory", name=f"file{rows}", file=str(path), compensation="off")
                )
        except DaemonError as exc:
            return str(exc)

    return send


def many_clients(n: int) -> Callable[[Path], str]:
    def send(work: Path) -> str:
        out: list[str] = []

        def one() -> None:
            try:
                with client(work) as c:
                    c.call("status")
                    out.append("ok")
            except Exception as exc:
                out.append(type(exc).__name__)

        threads = [threading.Thread(target=one) for _ in range(n)]
        for th in threads:
            th.start()
        for th in threads:
            th.join(60)
        return f"{out.count('ok')}/{n} answered"

    return send


def slow_client(seconds: float) -> Callable[[Path], str]:
    def send(work: Path) -> str:
        line = json.dumps({"cmd": "status", "id": 1}).encode() + b"\n"
        return _raw(work, line, chunk=1, pause_s=seconds / len(line))[:40]

    return send


def tiny_jog(speed: float) -> Callable[[Path], str]:
    def send(work: Path) -> str:
        try:
            with client(work) as c:
                return json.dumps(c.call("jog", segment=1, theta_rad=0.2, phi_rad=0.0, speed=speed))
        except DaemonError as exc:
            return str(exc)

    return send


def start_run(work: Path, seconds: float = 30.0) -> dict:
    traj = tj.go_and_return(theta_max_rad=0.6, rate_rad_s=0.6 / (seconds / 2))
    with client(work) as c:
        st = c.call("status")
        if st["fault"] is not None or not st["enabled"]:
            c.call("reset_fault", confirm=True)
            c.call("enable")
        return c.call("trajectory", name="battery", samples=traj.rows(), compensation="model")


def run_one(work: Path, name: str, stressor: Callable[[Path], str], stop_after_s: float) -> dict:
    """A trajectory, ``stressor`` in a thread, ``stop`` after ``stop_after_s``; the record."""
    start_run(work)
    time.sleep(0.5)
    with client(work) as c:
        before = c.call("status")
    t_before = time.monotonic()
    result: dict[str, Any] = {}
    th = threading.Thread(target=lambda: result.update(reply=stressor(work)), daemon=True)
    th.start()
    time.sleep(stop_after_s)
    with client(work) as c:
        t0 = time.monotonic()
        stop = c.call("stop")
        stop_s = time.monotonic() - t0
    th.join(180)
    with client(work) as c:
        after = c.call("status")
    window_s = time.monotonic() - t_before
    lb, la = before["loop"], after["loop"]
    return {
        "name": name,
        "reply": str(result.get("reply", "(no reply)"))[:160],
        "cycles_waited": stop["cycles_waited"],
        "stop_reply_s": round(stop_s, 4),
        "window_s": round(window_s, 2),
        "cycles": la["cycles"] - lb["cycles"],
        "long_cycles": la["long_cycles"] - lb["long_cycles"],
        "missed_cycles": la["missed_cycles"] - lb["missed_cycles"],
        "lateness_max_us": la["timing"]["lateness_max_us"],
        "lateness_histogram": la["timing"]["lateness_histogram"],
        "drive_faults": [t for t in after["trips"] if t["cause"].startswith(("fault", "emcy"))],
        "fault": after["fault"],
    }


def recover(work: Path) -> None:
    with client(work) as c, contextlib.suppress(DaemonError):
        c.call("reset_fault", confirm=True)
        c.call("enable")
