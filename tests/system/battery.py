"""Issue #21's battery: hostile and unlucky requests while a trajectory runs, ``stop`` in the
middle of each, and what the loop says about it. Used by ``tests/system/test_stop_battery.py``
(light) and ``benchmarks/bench_stop_battery.py`` (full, prints the histograms).

Each stressor runs in a thread while a trajectory runs on the simulated rig; in its middle a
``stop`` is sent. What is recorded:

- the stop on the bus: the reply's ``bus`` (:class:`cdcr_ctl.daemon.bustap.StopBusTap` on the
  run's CAN traffic log): request arrival to the first quick-stop controlword frame, in ms and
  loop periods, and the SYNC frames (bus cycles) sent in between; the same from the client's
  send (``time.time()`` is one clock for both processes);
- the machine's floor: ``timer_floor.py`` (the loop's clock and sleep doing nothing, in a process
  of its own) runs through the stressor's window; its lateness quantiles against the loop's,
  taken from the run's rows (the window's cycles);
- counters and rows: the run's share of the loop's global counters (``status`` ``runs``) against
  the deadlines missed and long cycles its rows report, and one row per cycle.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from syshelp import client

from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon.client import DaemonError
from cdcr_ctl.runlog import load_run

FLOOR_SCRIPT = Path(__file__).with_name("timer_floor.py")
#: The floor's SCHED_FIFO priority (0: SCHED_OTHER): the daemon's loop thread's when a caller
#: runs the daemon real-time (``bench_stop_battery.py --rt``: ``control.realtime_priority`` + 1,
#: :func:`cdcr_ctl.control.timing.raise_loop_priority`).
FLOOR_PRIORITY = 0
#: Lateness quantiles compared (loop against floor).
QUANTILES = (50.0, 99.0, 99.9, 100.0)


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
        for attempt in range(3):
            st = c.call("status")
            if st["fault"] is None and st["enabled"]:
                break
            try:
                c.call("reset_fault", confirm=True)
                c.call("enable")
            except DaemonError as exc:
                # Between windows, not in one: a loaded machine can lose a heartbeat while the
                # drives are brought up again; say so and try again.
                print(f"start_run: enable attempt {attempt + 1} failed: {exc}")
                time.sleep(1.0)
        return c.call("trajectory", name="battery", samples=traj.rows(), compensation="model")


class Floor:
    """``timer_floor.py`` in its own process for a window: ``with Floor(period) as f: ...``, then
    ``f.lateness_us`` (one value per cycle it ran)."""

    def __init__(self, period_s: float, tmp: Path, priority: int = FLOOR_PRIORITY) -> None:
        self.period_s, self.priority = period_s, priority
        self.out = tmp / f"floor-{os.getpid()}-{time.monotonic_ns()}.npy"
        self.lateness_us = np.zeros(0)

    def __enter__(self) -> Floor:
        self.proc = subprocess.Popen(
            [
                sys.executable,
                str(FLOOR_SCRIPT),
                repr(self.period_s),
                str(self.out),
                str(self.priority),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if line.strip() != "ready":
            self.proc.kill()
            raise RuntimeError(f"timer floor did not start: {line!r}")
        return self

    def __exit__(self, *exc: object) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()  # ends the floor loop
        self.proc.wait(60)
        if self.out.exists():
            self.lateness_us = np.load(self.out)
            self.out.unlink()


def quantiles_us(values: np.ndarray) -> dict[str, float]:
    """``p50``, ``p99``, ``p99.9``, ``max`` of ``values`` (us); NaN when empty."""
    if len(values) == 0:
        return {_qname(q): float("nan") for q in QUANTILES}
    vals = np.percentile(values, QUANTILES)
    return {_qname(q): float(v) for q, v in zip(QUANTILES, vals, strict=True)}


def _qname(q: float) -> str:
    return "max" if q == 100.0 else f"p{q:g}"


def _flagged(events: np.ndarray) -> tuple[int, int]:
    """(deadlines missed, long cycles) the rows' ``event`` column reports."""
    missed = long_ = 0
    for ev in events:
        ev = str(ev)
        if "late: " in ev:
            missed += int(ev.split("late: ")[1].split()[0])
        if "long: previous cycle" in ev:
            long_ += 1
    return missed, long_


def _rows_of(log_dir: str, timeout_s: float = 60.0) -> Any:
    """The run's log once closed (its writer ends after the run)."""
    end = time.monotonic() + timeout_s
    while True:
        run = load_run(log_dir)
        if run.ended is not None or time.monotonic() > end:
            return run
        time.sleep(0.2)


def run_one(
    work: Path,
    name: str,
    stressor: Callable[[Path], str],
    stop_after_s: float,
    period_s: float,
    tmp: Path,
    floor_priority: int = FLOOR_PRIORITY,
) -> dict:
    """A trajectory, ``stressor`` in a thread, ``stop`` after ``stop_after_s``; the record."""
    started = start_run(work)
    lead_s = 0.5
    time.sleep(lead_s)
    with client(work) as c:
        before = c.call("status")
    t_before = time.monotonic()
    result: dict[str, Any] = {}
    with Floor(period_s, tmp, floor_priority) as floor:
        th = threading.Thread(target=lambda: result.update(reply=stressor(work)), daemon=True)
        th.start()
        time.sleep(stop_after_s)
        with client(work) as c:
            t0 = time.monotonic()
            sent_wall = time.time()
            stop = c.call("stop")
            stop_s = time.monotonic() - t0
    th.join(180)
    with client(work) as c:
        after = c.call("status")
    window_s = time.monotonic() - t_before
    lb, la = before["loop"], after["loop"]
    run_info = next((r for r in after["runs"] if r["id"] == started["run"]), None)
    rec: dict[str, Any] = {
        "name": name,
        "reply": str(result.get("reply", "(no reply)"))[:160],
        "cycles_waited": stop["cycles_waited"],
        "bus": stop.get("bus"),
        "stop_reply_s": round(stop_s, 4),
        "window_s": round(window_s, 2),
        "cycles": la["cycles"] - lb["cycles"],
        "long_cycles": la["long_cycles"] - lb["long_cycles"],
        "missed_cycles": la["missed_cycles"] - lb["missed_cycles"],
        "lateness_max_us": la["timing"]["lateness_max_us"],
        "lateness_histogram": la["timing"]["lateness_histogram"],
        "drive_faults": [t for t in after["trips"] if t["cause"].startswith(("fault", "emcy"))],
        # Every trip of the window but the operator's stop (a lost heartbeat, no feedback, ...).
        "trips": [
            f"{t['cause']}: {t['detail']}"[:90]
            for t in after["trips"]
            if t not in before["trips"] and t["cause"] != "operator_stop"
        ],
        "fault": after["fault"],
        "floor_us": quantiles_us(floor.lateness_us),
        "floor_cycles": len(floor.lateness_us),
        "run_counters": run_info,
    }
    bus = rec["bus"]
    if bus is not None:
        # From the client's send (connect, server, parse included): one wall clock for both.
        rec["bus_from_send_ms"] = round((bus["quick_stop_wall_s"] - sent_wall) * 1e3, 3)
    if started.get("log_dir"):
        run = _rows_of(started["log_dir"])
        t = run.t_s
        window = t >= t[0] + lead_s if len(t) else np.zeros(0, bool)
        lateness = run.column("lateness_us")
        rec["loop_us"] = quantiles_us(lateness[window])
        missed, long_ = _flagged(run.column("event"))
        cyc = run.column("cycle")
        rec["rows"] = {
            "rows": len(t),
            "missed_flagged": missed,
            "long_flagged": long_,
            "cycles_contiguous": bool(len(cyc) == 0 or (np.diff(cyc) == 1).all()),
            "first_cycle": int(cyc[0]) if len(cyc) else None,
            "last_cycle": int(cyc[-1]) if len(cyc) else None,
        }
    return rec


def counters_agree(rec: dict) -> bool:
    """The run's share of the loop's counters equals what its rows report, every cycle a row."""
    rows, ctr = rec.get("rows"), rec.get("run_counters")
    if rows is None or ctr is None:
        return False
    return (
        rows["cycles_contiguous"]
        and rows["rows"] == ctr["rows"]
        and rows["first_cycle"] == ctr["first_cycle"]
        and rows["last_cycle"] == ctr["last_cycle"]
        and rows["missed_flagged"] == ctr["missed_cycles"]
        and rows["long_flagged"] == ctr["long_cycles"]
    )


def recover(work: Path) -> None:
    with client(work) as c, contextlib.suppress(DaemonError):
        c.call("reset_fault", confirm=True)
        c.call("enable")
