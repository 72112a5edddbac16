"""Start the simulated rig and the daemon as separate processes, as `cdcr-ctl demo` does."""

from __future__ import annotations

import contextlib
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from standin import RT_PRIORITY, SIM_ABOVE, standin_realtime

from cdcr_ctl.cli.demo import SIM_NICE, _cli, make_session, running, wait_for_socket
from cdcr_ctl.daemon.client import ControlClient

ROOT = Path(__file__).resolve().parents[2]
# The clean world: these tests exercise the plumbing, not the physics (the default world's lost
# motion makes an uncompensated cable go slack, which the tension limit rightly trips on).
TRUTH = ROOT / "config" / "sim" / "qi2023-truth-clean.yaml"


@contextlib.contextmanager
def session(tmp_path: Path, tcp_links: bool = True, realtime_daemon: bool = False):
    """(work dir, rig config, sim config, runs dir) with short paths (sockets need < 108 chars).
    ``realtime_daemon``: the rig config asks for SCHED_FIFO :data:`RT_PRIORITY`, as a lab PC's
    unit runs the daemon (:func:`realtime`).
    ``tcp_links``: the simulated CAN adapter and load cells on free loopback TCP ports (False:
    on ptys linked to ``work/can`` and ``work/loadcells``). Over a pty, the bytes wait for the
    kernel's tty worker thread, which runs time-shared whatever the simulator's and the daemon's
    priority: beside ``stress-ng --cpu 2`` a FIFO-to-FIFO pty took up to 115 ms, loopback TCP
    6.5 ms (``benchmarks/bench_link.py``), and soaks tripped on drives silent for 0.25-0.3 s
    and load-cell samples 0.5 s old."""
    work = Path(tempfile.mkdtemp(prefix="cdcr-t-", dir="/tmp"))
    runs = tmp_path / "runs"
    runs.mkdir()
    rig, sim = make_session(TRUTH, work, runs, tcp_links=tcp_links)
    if realtime_daemon:
        realtime(rig)
    try:
        yield work, rig, sim, runs
    finally:
        shutil.rmtree(work, ignore_errors=True)


@contextlib.contextmanager
def start_sim(sim: Path, log: Path, *args: str):
    """The simulated rig (``cdcr-ctl sim SIM ARGS``) as a process: stand-in hardware, at
    SCHED_FIFO :data:`standin.STANDIN_PRIORITY` with every thread and child once it is ready
    (:mod:`standin`; at :data:`~cdcr_ctl.cli.demo.SIM_NICE` until then, and where FIFO is not
    permitted)."""
    with running(_cli("sim", str(sim), *args), log, ready='"ready"', nice=SIM_NICE) as proc:
        standin_realtime(proc.pid)
        yield proc


def start_daemon(rig: Path, log: Path):
    return running(_cli("--config", str(rig), "daemon"), log)


def set_rate(rig: Path, rate_hz: float, rt: int) -> None:
    """The session's rig config at loop and SYNC rate ``rate_hz`` and real-time priority ``rt``
    (``control.realtime_priority``; 0: SCHED_OTHER)."""
    doc = yaml.safe_load(rig.read_text())
    doc.setdefault("control", {})["rate_hz"] = rate_hz
    doc["control"]["realtime_priority"] = rt
    doc.setdefault("can", {})["sync_period_s"] = 1.0 / rate_hz
    rig.write_text(yaml.safe_dump(doc, sort_keys=False))


def realtime(rig: Path, sim_pid: int | None = None, rt: int = RT_PRIORITY) -> None:
    """The session's daemon at SCHED_FIFO ``rt`` (its rig config, read when it starts) and, given
    ``sim_pid``, every thread of that running simulator and of its children at ``rt`` +
    :data:`SIM_ABOVE` (:func:`standin.standin_realtime`). Where not permitted the simulator
    stays as it is."""
    doc = yaml.safe_load(rig.read_text())
    doc.setdefault("control", {})["realtime_priority"] = rt
    rig.write_text(yaml.safe_dump(doc, sort_keys=False))
    if sim_pid is not None:
        standin_realtime(sim_pid, rt + SIM_ABOVE)


def client(work: Path) -> ControlClient:
    return ControlClient(work / "control.sock")


def wait_status(work: Path, pred, timeout_s: float = 20.0) -> dict:
    end = time.monotonic() + timeout_s
    st: dict = {}
    while time.monotonic() < end:
        with contextlib.suppress(Exception), client(work) as c:
            st = c.call("status")
            if pred(st):
                return st
        time.sleep(0.1)
    raise AssertionError(f"status never matched; last: {st}")


def wait_progress(
    work: Path,
    pred: Callable[[dict], bool],
    progress: Callable[[dict], float],
    stall_s: float = 30.0,
) -> dict:
    """The daemon's status once ``pred`` holds, waiting as long as ``progress(status)`` (a run's
    simulated time, say) keeps growing: AssertionError once it has not grown for ``stall_s``
    (s, wall clock). A deadline from measured progress, not from the machine's speed."""
    last, since = float("-inf"), time.monotonic()
    while True:
        st = wait_status(work, lambda _st: True)
        if pred(st):
            return st
        now, value = time.monotonic(), progress(st)
        if value > last:
            last, since = value, now
        elif now - since > stall_s:
            raise AssertionError(f"no progress for {stall_s} s (stuck at {last}); last: {st}")
        time.sleep(0.1)


def wait_run_end(work: Path, run_id: str, timeout_s: float) -> tuple[dict, dict]:
    """(the run's entry in ``status["runs"]``, that status) once run ``run_id`` has ended."""
    st = wait_status(work, lambda s: any(r["id"] == run_id for r in s["runs"]), timeout_s)
    return next(r for r in st["runs"] if r["id"] == run_id), st


def status_of_run(work: Path, run_id: str) -> tuple[dict, dict] | None:
    """None while run ``run_id`` runs (or is not yet taken up); once it has ended, its entry in
    ``status["runs"]`` and the status's fault."""
    with client(work) as c:
        st = c.call("status")
    done = [r for r in st["runs"] if r["id"] == run_id]
    return (done[0], st["fault"]) if done and st["run"] is None else None


def relaunch(rig: Path, work: Path, log: Path) -> None:
    """A new daemon starts after a killed one, finds the drives disabled (their heartbeat
    consumers noticed the master's death), and enables them."""
    with start_daemon(rig, log) as d:
        wait_for_socket(work / "control.sock", d, log)
        st = wait_status(work, lambda s: all(x["state"] != "UNKNOWN" for x in s["drives"]))
        assert all(x["state"] != "OPERATION ENABLED" for x in st["drives"])
        with client(work) as c:
            c.call("reset_fault", confirm=True)
            c.call("enable")
            assert c.call("status")["enabled"]


__all__ = [
    "RT_PRIORITY",
    "SIM_ABOVE",
    "client",
    "realtime",
    "relaunch",
    "session",
    "set_rate",
    "start_daemon",
    "start_sim",
    "status_of_run",
    "wait_for_socket",
    "wait_progress",
    "wait_run_end",
    "wait_status",
]


def lasting_run(work: Path, start: Callable[[int], dict], last_s: float, attempts: int = 3) -> dict:
    """``start(attempt)`` a run (its answer has ``run``) until one is still running ``last_s``
    later; return that answer. For tests whose subject is a run killed or stopped while it
    runs: a run a loaded machine trips before that (a drive's heartbeat lost under stress-ng)
    is started again (``start`` must reset a fault), up to ``attempts`` times."""
    run: dict = {}
    for attempt in range(attempts):
        res = start(attempt)
        time.sleep(last_s)
        with client(work) as c:
            run = c.call("status").get("run") or {}
        if run.get("state") == "running" and run.get("id") == res["run"]:
            return res
    pytest.fail(f"no run lasted {last_s} s on this machine in {attempts} attempts; last: {run}")
