"""Helpers for the fault matrix: the simulated rig with its fault channel, the daemon, and the
measurements of how fast the drives reached a safe state.

Times are ``time.monotonic()`` values: the simulator stamps the injection and every drive state
change with its own monotonic clock, which on Linux is the same clock in every process.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from syshelp import start_sim

from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon.client import ControlClient, DaemonError
from cdcr_ctl.runlog import load_run
from cdcr_ctl.sim.faults import SAFE_STATES, FaultClient

#: How long the measurements wait for the drives to settle (s).
SETTLE_TIMEOUT_S = 10.0
#: A drive whose CSP target has not changed for this long is holding (s).
HOLD_QUIET_S = 0.3


def start_sim_with_faults(sim: Path, faults: Path, log: Path):
    """``cdcr-ctl sim SIM --faults FAULTS`` as a subprocess, stand-in hardware
    (:func:`syshelp.start_sim`; context manager)."""
    return start_sim(sim, log, "--faults", str(faults))


def call(work: Path, cmd: str, **args: Any) -> Any:
    with ControlClient(work / "control.sock", timeout_s=10) as c:
        return c.call(cmd, **args)


def status(work: Path) -> dict:
    return call(work, "status")


def wait_for(pred, timeout_s: float, what: str, poll_s: float = 0.02):
    """Poll ``pred()`` until it returns something truthy; AssertionError naming ``what`` and the
    last value or exception ``pred`` gave."""
    end = time.monotonic() + timeout_s
    last: Any = None
    while time.monotonic() < end:
        try:
            last = pred()
        except Exception as exc:  # retried; the last one is reported
            last = exc
        else:
            if last:
                return last
        time.sleep(poll_s)
    raise AssertionError(f"timed out waiting for {what} (last: {last!r})")


def _enable_or_reset(work: Path) -> bool:
    """``enable``; True when accepted. A drive still in FAULT, or a trip latched meanwhile (a
    starved machine: the stand-in drives fell silent for a moment during the enable, and the
    group latched ``no_feedback``; seen under ``stress-ng --cpu 2``), gets a ``reset_fault``,
    as an operator would, and the enable is tried again."""
    try:
        call(work, "enable")
    except DaemonError as exc:
        if "reset_faults() first" not in str(exc) and status(work)["fault"] is None:
            raise
        call(work, "reset_fault", confirm=True)
        return False
    return True


def make_ready(work: Path) -> None:
    """Clear any trip (fault reset) and enable the drives."""
    st = status(work)
    if st["fault"] is not None or any(d["state"] == "FAULT" for d in st["drives"]):
        # A drive just back on the bus needs its feedback flowing before a reset can be
        # confirmed: retry for a while.
        wait_for(lambda: call(work, "reset_fault", confirm=True), 5, "fault reset", poll_s=0.3)
    # A drive back from bus off may still report FAULT to the enable that follows a confirmed
    # reset (seen once under stress-ng: "node 2: 0x0000 in FAULT (no EMCY): reset_faults()
    # first"): reset again and retry, for a while, as an operator would.
    wait_for(lambda: _enable_or_reset(work), 5, "enable", poll_s=0.3)
    wait_for(
        lambda: all(d["state"] == "OPERATION ENABLED" for d in status(work)["drives"]),
        10,
        "drives enabled",
    )
    # Known loop behaviour (reported): the first command after re-enabling is checked against
    # the command sent before the quick stop, so a drive that moved meanwhile trips the velocity
    # limit once (HALT, drives stay enabled). Acknowledge that one trip and nothing else.
    for _ in range(5):
        time.sleep(0.15)
        fault = status(work)["fault"]
        if fault is None:
            return
        assert fault["cause"].startswith("velocity_limit"), fault
        call(work, "reset_fault", confirm=True)
    raise AssertionError(f"the rig keeps tripping after enable: {status(work)['fault']}")


#: Trips of a run before any fault was injected that a starved machine causes (the stand-in
#: drives or sensors fell silent), not the fault under test: such a run is started again.
STARVED_CAUSES = ("heartbeat:", "no_feedback:", "stale_tension:", "stale_tracker:")
#: Runs :func:`start_moving_run` starts before it gives up.
START_ATTEMPTS = 3


def start_moving_run(work: Path, name: str, seconds: float = 8.0, seed: int = 0) -> dict:
    """A logged trajectory that keeps every cable moving for ``seconds``; waits until the log
    has rows on disk and the run is well under way.

    A run that trips on one of :data:`STARVED_CAUSES` before that (nothing has been injected
    yet) is reported as a warning and started again after :func:`make_ready`, up to
    :data:`START_ATTEMPTS` runs; any other early end fails at once."""
    rate = 0.6 / (seconds / 4)
    traj = tj.go_and_return(theta_max_rad=0.6, rate_rad_s=rate, phi_rad=0.4 + seed)
    attempt = 1
    while True:
        res = call(
            work, "trajectory", name=name, samples=traj.rows(), compensation="model", log=True
        )
        early = _wait_under_way(work, res, name)
        if early is None:
            return res
        cause = (early["fault"] or {}).get("cause", "")
        if not cause.startswith(STARVED_CAUSES) or attempt == START_ATTEMPTS:
            raise AssertionError(f"{name} ended early (run {attempt}): {early}")
        warnings.warn(f"{name}: run {attempt} tripped before any injection: {early}", stacklevel=2)
        make_ready(work)
        attempt += 1


def _wait_under_way(work: Path, res: dict, name: str) -> dict | None:
    """None once the run's log has 100 rows on disk; the run and the fault when it ended first."""
    end = time.monotonic() + 15
    while rows_on_disk(res["log_dir"]) <= 100:
        st = status(work)
        done = [r for r in st["runs"] if r["id"] == res["run"]]
        if st["run"] is None and done:
            # (A run posted but not yet picked up by the loop's next cycle is in neither.)
            return {"run": done[0], "fault": st["fault"]}
        assert time.monotonic() < end, f"{name}: no rows on disk"
        time.sleep(0.02)
    return None


def rows_on_disk(run_dir: str) -> int:
    """Rows in the run's samples.csv; 0 before the writer process has made the file (a run's
    start does not wait for it: ``logging.writer: process``)."""
    if not (Path(run_dir) / "samples.csv").is_file():
        return 0
    return len(load_run(run_dir))


@dataclass
class SafeState:
    """When each drive reached a safe state after an injection: per node (s, SYNCs) from the
    injection; ``None`` for a node that never did within the wait."""

    per_node: dict[int, tuple[float, int] | None]
    states: dict[int, str]

    @property
    def worst_s(self) -> float:
        return max((v[0] for v in self.per_node.values() if v), default=math.inf)

    @property
    def worst_syncs(self) -> int:
        return max((v[1] for v in self.per_node.values() if v), default=10**9)

    @property
    def all_safe(self) -> bool:
        return all(v is not None for v in self.per_node.values())


def safe_after(fc: FaultClient, inj: dict, timeout_s: float = SETTLE_TIMEOUT_S) -> SafeState:
    """First state change of each drive into a safe state (QUICK STOP ACTIVE, SWITCH ON DISABLED,
    FAULT) after the injection ``inj`` (the fault channel's answer), measured in the simulator."""
    t0, syncs0 = inj["t_s"], {int(k): v for k, v in inj["syncs"].items()}

    def measure() -> SafeState | None:
        tr = fc.query("transitions", since_t_s=t0)["transitions"]
        drives = fc.query("drives")["drives"]
        per: dict[int, tuple[float, int] | None] = {}
        for d in drives:
            node = d["node"]
            first = next((x for x in tr if x["node"] == node and x["state"] in SAFE_STATES), None)
            per[node] = None if first is None else (first["t_s"] - t0, first["sync"] - syncs0[node])
        res = SafeState(per, {d["node"]: d["state"] for d in drives})
        return res if res.all_safe else None

    with contextlib.suppress(AssertionError):
        return wait_for(measure, timeout_s, "drives safe")
    drives = fc.query("drives")["drives"]
    return SafeState({d["node"]: None for d in drives}, {d["node"]: d["state"] for d in drives})


def hold_after(fc: FaultClient, inj: dict, timeout_s: float = SETTLE_TIMEOUT_S) -> SafeState:
    """Halt/hold reactions: when each drive's CSP target last changed after the injection (the
    drives stay enabled and hold). (0 s, 0 SYNCs) if it never changed after it."""
    t0, syncs0 = inj["t_s"], {int(k): v for k, v in inj["syncs"].items()}

    def measure() -> SafeState | None:
        drives = fc.query("drives")["drives"]
        now = time.monotonic()
        if any(now - d["target_changed"][0] < HOLD_QUIET_S for d in drives):
            return None
        per = {
            d["node"]: (
                max(0.0, d["target_changed"][0] - t0),
                max(0, d["target_changed"][1] - syncs0[d["node"]]),
            )
            for d in drives
        }
        return SafeState(per, {d["node"]: d["state"] for d in drives})

    with contextlib.suppress(AssertionError):
        return wait_for(measure, timeout_s, "drives holding")
    drives = fc.query("drives")["drives"]
    return SafeState({d["node"]: None for d in drives}, {d["node"]: d["state"] for d in drives})


def check_log(run_dir: str, cause: str | None) -> dict[str, Any]:
    """The run log after a fault: readable, cycles contiguous (no sample lost between the first
    and the last row), nothing dropped or lost while writing, the cause in ``event`` and in
    ``run.yaml``'s reason (when given). Returns a summary."""
    if cause is not None:  # the loop closes the log without waiting: let the writer finish
        wait_for(lambda: load_run(run_dir).ended, 10, f"{run_dir} closed")
    run = load_run(run_dir)
    cycles = run.data["cycle"]
    gaps = int(np.sum(np.diff(cycles) != 1))
    t = run.t_s
    assert len(run) > 50, f"{run_dir}: only {len(run)} rows"
    assert gaps == 0, f"{run_dir}: {gaps} gaps in the cycle column"
    assert all(b > a for a, b in itertools.pairwise(t))
    out = {"rows": len(run), "ended": run.ended, "warnings": run.warnings}
    if cause is not None:
        events = [e for e in run.data["event"] if isinstance(e, str) and e]
        assert any(e.startswith(cause) for e in events), f"{cause} not in events {events[:5]}"
        assert run.ended is not None and run.ended["reason"].startswith(cause), run.ended
        rows = run.ended["rows"]
        assert rows["dropped"] == 0 and rows["lost"] == 0 and rows["written"] == rows["queued"]
        assert rows["written"] == len(run)
    return out
