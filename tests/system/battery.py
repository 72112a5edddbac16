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
    ``f.lateness_us`` (one value per cycle it ran) and ``f.deadlines_s`` (each cycle's deadline,
    ``time.monotonic``). ``cpu``: keep the process on that CPU."""

    def __init__(
        self, period_s: float, tmp: Path, priority: int = FLOOR_PRIORITY, cpu: int | None = None
    ) -> None:
        self.period_s, self.priority, self.cpu = period_s, priority, cpu
        self.out = tmp / f"floor-{os.getpid()}-{cpu}-{time.monotonic_ns()}.npy"
        self.lateness_us = np.zeros(0)
        self.deadlines_s = np.zeros(0)

    def __enter__(self) -> Floor:
        self.spawn()
        self.wait_ready()
        return self

    def spawn(self) -> None:
        args = [sys.executable, str(FLOOR_SCRIPT), repr(self.period_s), str(self.out)]
        args += [str(self.priority)] + ([] if self.cpu is None else [str(self.cpu)])
        self.proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def wait_ready(self) -> None:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if line.strip() != "ready":
            self.proc.kill()
            raise RuntimeError(f"timer floor did not start: {line!r}")

    def __exit__(self, *exc: object) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()  # ends the floor loop
        self.proc.wait(60)
        if self.out.exists():
            arr = np.load(self.out).reshape(-1, 2)
            self.lateness_us, self.deadlines_s = arr[:, 0], arr[:, 1]
            self.out.unlink()


class MachineFloor:
    """The machine's floor through a window: one :class:`Floor` on each CPU the daemon may run
    on (this process's affinity, which the daemon inherits). The loop's thread moves between
    CPUs, and a stall of one CPU (on this virtual machine, about one wake-up in several seconds
    comes 2-7 ms late on one CPU and not on the other) reaches only what runs there at that
    moment; one floor process would see its own CPU's stalls only. ``lateness_us`` and
    ``deadlines_s`` hold every floor's cycles; :attr:`span_s` is the time all of them ran."""

    def __init__(self, period_s: float, tmp: Path, priority: int = FLOOR_PRIORITY) -> None:
        cpus = sorted(os.sched_getaffinity(0))
        self.floors = [Floor(period_s, tmp, priority, cpu) for cpu in cpus]
        self.lateness_us = np.zeros(0)
        self.deadlines_s = np.zeros(0)
        self.span_s = (np.nan, np.nan)

    def __enter__(self) -> MachineFloor:
        for f in self.floors:
            f.spawn()
        for f in self.floors:
            f.wait_ready()
        return self

    def __exit__(self, *exc: object) -> None:
        for f in self.floors:
            f.__exit__(*exc)
        ran = [f for f in self.floors if len(f.deadlines_s)]
        if ran:
            self.lateness_us = np.concatenate([f.lateness_us for f in ran])
            self.deadlines_s = np.concatenate([f.deadlines_s for f in ran])
            self.span_s = (
                max(f.deadlines_s[0] for f in ran),
                min(f.deadlines_s[-1] for f in ran),
            )

    def in_span_us(self) -> np.ndarray:
        """The floors' lateness (us) of the cycles due within :attr:`span_s`."""
        lo, hi = self.span_s
        return self.lateness_us[(self.deadlines_s >= lo) & (self.deadlines_s <= hi)]


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
    """A trajectory, ``stressor`` in a thread, ``stop`` after ``stop_after_s``; the record.

    The machine's floor (:class:`MachineFloor`) runs from before the run starts until the
    stressor ended; the loop's rows are compared with it over the same span (the run's start
    included)."""
    lead_s = 0.5
    result: dict[str, Any] = {}
    with client(work) as c:
        before = c.call("status")
    t_before = time.monotonic()
    with MachineFloor(period_s, tmp, floor_priority) as floor:
        started = start_run(work)
        time.sleep(lead_s)
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
        "floor_us": quantiles_us(floor.in_span_us()),
        "floor_cycles": len(floor.in_span_us()),
        "floor_cpus": len(floor.floors),
        "run_counters": run_info,
        "front": _front_delta(before.get("front"), after.get("front")),
    }
    bus = rec["bus"]
    if bus is not None:
        # From the client's send (connect, server, parse included): one wall clock for both.
        rec["bus_from_send_ms"] = round((bus["quick_stop_wall_s"] - sent_wall) * 1e3, 3)
    if started.get("log_dir"):
        run = _rows_of(started["log_dir"])
        t = run.t_s
        lateness = run.column("lateness_us")
        t0 = after["loop"].get("t0_clock_s")
        lo, hi = floor.span_s
        if t0 is not None and np.isfinite(lo):
            # The rows due while every floor ran: the same span for both.
            window = (t0 + t >= lo) & (t0 + t <= hi)
            rec["late_events"] = late_events(
                t0 + t[window],
                lateness[window],
                run.column("event")[window],
                floor.deadlines_s,
                floor.lateness_us,
                after.get("rig_command_log", []),
                period_s,
            )
        else:
            window = t >= t[0] + lead_s if len(t) else np.zeros(0, bool)
        rec["loop_us"] = quantiles_us(lateness[window])
        rec["loop_rows_compared"] = int(window.sum())
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


#: A loop cycle this much later than its deadline (in periods) is listed by :func:`late_events`.
LATE_EVENT_PERIODS = 1.0


def late_events(
    loop_due_s: np.ndarray,
    loop_late_us: np.ndarray,
    loop_events: np.ndarray,
    floor_due_s: np.ndarray,
    floor_late_us: np.ndarray,
    commands: list,
    period_s: float,
    around_s: float = 0.01,
) -> list[dict[str, Any]]:
    """The loop's cycles later than :data:`LATE_EVENT_PERIODS` periods inside the floor's span,
    each with its time from the floor's start (s), the floor's worst lateness within
    ``around_s`` of it (us: the same stall seen by a process doing nothing is the machine's),
    whether a floor stall explains it (``machine``, see below) and the rig process's commands
    whose handling overlapped the stall (``commands``: status ``rig_command_log``, (name,
    start, end, CPU ms) on the same clock).

    ``machine``: some floor cycle was at least as late as this one less one period (the
    acceptance's allowance) and its stall overlapped this one's. A row's stall lies within its
    lateness before or after its deadline (a row after skipped deadlines counts from the first
    one; both the loop's rows and the floor's count so), so two stalls overlap when their
    deadlines are less than the sum of both latenesses and one period apart."""
    out: list[dict[str, Any]] = []
    if not len(floor_due_s):
        return out
    lo, hi = floor_due_s[0], floor_due_s[-1]
    period_us = period_s * 1e6
    for i in np.flatnonzero(loop_late_us > LATE_EVENT_PERIODS * period_us):
        due = float(loop_due_s[i])
        late_s = loop_late_us[i] * 1e-6
        near = np.abs(floor_due_s - due) <= around_s + late_s
        overlap = np.abs(floor_due_s - due) <= late_s + floor_late_us * 1e-6 + period_s
        machine = bool(np.any(overlap & (floor_late_us >= loop_late_us[i] - period_us)))
        out.append(
            {
                "at_s": round(due - lo, 4),
                "in_floor_span": bool(lo <= due <= hi),
                "event": str(loop_events[i]),
                "late_us": round(float(loop_late_us[i]), 1),
                "floor_near_us": round(float(floor_late_us[near].max()), 1) if near.any() else None,
                "machine": machine,
                "commands": [
                    f"{c[0]} ({(c[2] - c[1]) * 1e3:.1f} ms, cpu {c[3]:.1f} ms)"
                    for c in commands
                    if c[1] <= due + late_s and c[2] >= due - around_s
                ],
            }
        )
    return out


def _front_delta(before: dict | None, after: dict | None) -> dict | None:
    """The window's ``status`` requests at the daemon's front process and the round trips they
    cost the rig process (status is coalesced); None for a one-process daemon."""
    if not before or not after:
        return None
    return {
        k: after[k] - before[k] for k in ("status_requests", "status_round_trips") if k in after
    }


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
