"""``stop`` under client load, timed end to end: from the client's send to the first drive that
took the quick-stop controlword off the CAN bus. Used by ``tests/system/test_stop_under_load.py``
(light) and ``benchmarks/bench_stop_load.py`` (20 trials per load, 250 Hz and 1 kHz).

The loads run in processes of their own (:func:`load_process`), so the client that sends ``stop``
(this process) shares no interpreter lock with them, as an operator's ``cdcr-ctl stop`` shares
none with a misbehaving script:

- ``status``: ``n`` clients, each on its own connection, asking ``status`` back to back;
- ``big``: ``n`` clients, each sending 16 MB request lines (refused at ``MAX_LINE_BYTES`` after
  being read to their end) back to back;
- ``slowloris``: ``n`` connections to the control socket and ``n`` to the stop socket, each
  sending a byte of a line every 0.2 s and never ending it (reopened when the daemon drops it).

The independent listener is the simulated drive itself: the simulator stamps each drive's state
changes with ``time.monotonic()`` (one clock for every process on Linux) and serves them on its
fault channel (:mod:`cdcr_ctl.sim.faults`, ``transitions``). A trial's latency is from the
``time.monotonic()`` taken just before the client sends ``stop`` on its connection, to the
first drive entering QUICK STOP ACTIVE (it has received controlword 0x0002 off the bus: the RPDO,
or the SDO to 0x6040 for a drive not OPERATIONAL); the SYNC frames that drive saw in between are
counted from its SYNC count just before the send. The daemon's own record of the frame (its CAN
traffic log's stop tap, the reply's ``bus``: when the adapter took the frame) is kept beside it
(``daemon_bus_ms``), from the send's ``time.time()``.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon.client import ControlClient, DaemonError, recv_line
from cdcr_ctl.daemon.protocol import encode_request, stop_socket_path
from cdcr_ctl.errors import RigError

#: Bytes of one ``big`` request line (16 MB of numbers: longer than ``MAX_LINE_BYTES``).
BIG_BYTES = 16 * 1024 * 1024
#: Pause between the bytes a slow-loris connection sends (s).
LORIS_PAUSE_S = 0.2
#: The acceptance's allowance on top of two loop periods (s).
ALLOWANCE_S = 0.050
#: Longest wait for the drive's quick stop to show in the simulator after the send (s).
OBSERVE_TIMEOUT_S = 5.0


# ---------------------------------------------------------------------------- the loads
def _status_client(path: str, stop: Any, count: Any) -> None:
    while not stop.is_set():
        try:
            with ControlClient(path, timeout_s=60) as c:
                while not stop.is_set():
                    c.call("status")
                    with count.get_lock():
                        count.value += 1
        except (RigError, OSError, ValueError):
            time.sleep(0.05)


def _big_client(path: str, line: bytes, stop: Any, count: Any) -> None:
    while not stop.is_set():
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(120)
        try:
            s.connect(path)
            while not stop.is_set():
                s.sendall(line)
                buf = b""
                while b"\n" not in buf:
                    part = s.recv(65536)
                    if not part:
                        raise OSError("closed")
                    buf += part
                with count.get_lock():
                    count.value += 1
        except OSError:
            time.sleep(0.05)
        finally:
            s.close()


def _loris(path: str, stop: Any, count: Any) -> None:
    while not stop.is_set():
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            s.connect(path)
            with count.get_lock():
                count.value += 1
            for b in b'{"id": 1, "cmd": "stop", "args": {"mode": "quick_stop"' * 1000:
                if stop.wait(LORIS_PAUSE_S):
                    break
                s.send(bytes((b,)))
        except OSError:
            time.sleep(0.05)
        finally:
            s.close()


def _orphaned(parent: int, stop: Any) -> None:
    """Ends the load when the process that started it is gone (killed before its cleanup)."""
    while not stop.wait(0.5):
        if os.getppid() != parent:
            os._exit(0)


def load_process(kind: str, n: int, control: str, stop: Any, count: Any) -> None:
    """(a process's target) ``n`` clients of ``kind`` (see the module) until ``stop`` is set;
    ``count`` counts their answers (``status``, ``big``) or connections (``slowloris``).

    In a session of its own, as a script started elsewhere is: the kernel's fair scheduler
    shares the CPU between sessions (autogroups) first, and the operator's ``stop`` comes from
    another session than the flood's."""
    parent = os.getppid()
    os.setsid()
    threading.Thread(target=_orphaned, args=(parent, stop), daemon=True).start()
    threads = []
    if kind == "status":
        threads = [
            threading.Thread(target=_status_client, args=(control, stop, count)) for _ in range(n)
        ]
    elif kind == "big":
        line = b'{"cmd": "trajectory", "args": {"samples": [[' + b"0.0, " * (BIG_BYTES // 5)
        line += b"0]]}}\n"
        threads = [
            threading.Thread(target=_big_client, args=(control, line, stop, count))
            for _ in range(n)
        ]
    elif kind == "slowloris":
        stop_path = str(stop_socket_path(control))
        threads = [
            threading.Thread(target=_loris, args=(p, stop, count))
            for p in (control, stop_path)
            for _ in range(n)
        ]
    else:  # pragma: no cover - a caller's mistake
        raise ValueError(kind)
    for th in threads:
        th.daemon = True
        th.start()
    stop.wait()
    time.sleep(0.2)


@contextlib.contextmanager
def loaded(kind: str, n: int, control: Path, warm_s: float = 0.5) -> Iterator[Any]:
    """``kind`` load with ``n`` clients in a process of its own while the block runs; yields the
    answer (or connection) counter. ``warm_s``: time for the clients to connect first."""
    ctx = multiprocessing.get_context("spawn")
    stop, count = ctx.Event(), ctx.Value("q", 0)
    proc = ctx.Process(
        target=load_process, args=(kind, n, str(control), stop, count), name=f"load-{kind}"
    )
    proc.start()
    try:
        end = time.monotonic() + 60.0
        while count.value == 0 and time.monotonic() < end:
            time.sleep(0.05)
        time.sleep(warm_s)
        yield count
    finally:
        stop.set()
        proc.join(30)
        if proc.is_alive():
            proc.kill()
            proc.join(5)


# ---------------------------------------------------------------------------- one trial
def start_run(control: Path, seed: int, duration_s: float = 30.0) -> None:
    """Clear the last stop's trip, enable, and start a slow random trajectory, logged (its CAN
    traffic log times the stop on the daemon's side: the reply's ``bus``)."""
    with ControlClient(control, timeout_s=60) as c:
        with contextlib.suppress(DaemonError):
            c.call("reset_fault", confirm=True)
        c.call("enable")
        traj = tj.random_smooth(1, duration_s, 0.6, 0.3, seed=seed)
        c.call("trajectory", name=f"stopload{seed}", samples=traj.rows(), log=True)


def stop_trial(control: Path, fc: Any, period_s: float) -> dict[str, Any]:
    """Send ``stop`` as ``cdcr-ctl stop`` does (a new connection to the stop socket, the same
    line), timed from just before the send, and time it on the drives: the
    latency (ms), in loop periods, the SYNCs the first drive saw in between, the budget (2
    periods + :data:`ALLOWANCE_S`) and whether it held, and the reply."""
    syncs0 = {d["node"]: d["syncs"] for d in fc.query("drives")["drives"]}
    path = stop_socket_path(control)
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC) as s:
        s.settimeout(60)
        s.connect(str(path))
        line = encode_request("stop", {}, 1)  # what ControlClient.call("stop") sends there
        t_wall = time.time()
        t_send = time.monotonic()
        s.sendall(line)
        reply = json.loads(recv_line(s, str(path)))["result"]
    t_reply = time.monotonic()
    first = None
    end = time.monotonic() + OBSERVE_TIMEOUT_S
    while first is None and time.monotonic() < end:
        tr = fc.query("transitions", since_t_s=t_send)["transitions"]
        qs = [x for x in tr if x["state"] == "QUICK STOP ACTIVE"]
        first = min(qs, key=lambda x: x["t_s"]) if qs else None
        if first is None:
            time.sleep(0.02)
    budget_ms = (2 * period_s + ALLOWANCE_S) * 1e3
    out: dict[str, Any] = {
        "reply_ms": round((t_reply - t_send) * 1e3, 2),
        "reply": {k: reply.get(k) for k in ("cycles_waited", "note") if k in reply},
        "budget_ms": round(budget_ms, 1),
    }
    bus = reply.get("bus")
    if bus:
        # The daemon's own record: the quick-stop frame handed to the CAN adapter (wall clock).
        out["daemon_bus_ms"] = round((bus["quick_stop_wall_s"] - t_wall) * 1e3, 2)
    if first is None:
        out.update(latency_ms=None, holds=False)
        return out
    ms = (first["t_s"] - t_send) * 1e3
    out.update(
        latency_ms=round(ms, 2),
        periods=round(ms / 1e3 / period_s, 2),
        syncs=first["sync"] - syncs0[first["node"]],
        node=first["node"],
        holds=ms <= budget_ms,
    )
    return out


def wait_running(control: Path, timeout_s: float = 60.0) -> None:
    """Until a run is current and every drive is OPERATION ENABLED."""
    end = time.monotonic() + timeout_s
    st: dict = {}
    while time.monotonic() < end:
        with ControlClient(control, timeout_s=60) as c:
            st = c.call("status")
        if st.get("run") is not None and all(
            d["state"] == "OPERATION ENABLED" for d in st["drives"]
        ):
            return
        time.sleep(0.05)
    raise AssertionError(f"no run with the drives enabled; last status state {st.get('state')}")


#: Tries to get a run going before a trial (a starved machine may trip the rig meanwhile).
SETUP_TRIES = 4


def ready_run(control: Path, seed: int) -> list[str]:
    """A run going with the drives enabled; returns what went wrong on the way (trips of a
    starved machine, e.g. a heartbeat lost, cleared as an operator would), empty if nothing."""
    notes: list[str] = []
    for _ in range(SETUP_TRIES):
        try:
            start_run(control, seed)
            wait_running(control, timeout_s=20.0)
            return notes
        except (DaemonError, AssertionError) as exc:
            with ControlClient(control, timeout_s=60) as c:
                fault = c.call("status").get("fault")
            notes.append(f"{exc}"[:80] + (f" (trip {fault['cause']})" if fault else ""))
            time.sleep(0.3)
    raise AssertionError(f"no run could be started: {notes}")


def trials(control: Path, fc: Any, period_s: float, n: int, seed0: int) -> list[dict[str, Any]]:
    """``n`` stop trials, each on a fresh run (started and waited for under the load)."""
    out = []
    seed = seed0
    while len(out) < n:
        seed += 1
        notes = ready_run(control, seed)
        time.sleep(0.1 + 0.1 * (seed % 3))  # a different phase of the loop's cycle each time
        trial = {**stop_trial(control, fc, period_s), "setup_trips": notes}
        void = _stopped_before(control, trial)
        if void is not None and len(notes) < SETUP_TRIES:
            # The rig had tripped by itself (a starved machine) before the stop: nothing to
            # time. Counted in the next trial's setup notes, and the trial is made again.
            notes.append(void)
            continue
        out.append(trial)
    return out


def _stopped_before(control: Path, trial: dict[str, Any]) -> str | None:
    """The trip that stopped the drives before the trial's ``stop`` (none seen on the drives and
    the latched trip is not the operator's), or None."""
    if trial["latency_ms"] is not None:
        return None
    with ControlClient(control, timeout_s=60) as c:
        fault = c.call("status").get("fault")
    if fault and fault.get("cause") != "operator_stop":
        return f"tripped before the stop: {fault['cause']}"
    return None


__all__ = ["ALLOWANCE_S", "load_process", "loaded", "stop_trial", "trials", "wait_running"]
