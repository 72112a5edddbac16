"""Running a trajectory through the daemon and waiting for it: given up on when it stops
progressing.

Used by the commands that run trajectories and wait for each (``demo``, ``identify``,
``experiments``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from cdcr_ctl.daemon.client import ControlClient
from cdcr_ctl.errors import RigError

#: A run is given up on after this long without progress (s of wall time).
RUN_SLACK_S = 60.0
#: How often the daemon's status is asked while a run goes (s of wall time).
POLL_S = 0.2


def run_deadline(
    st: dict[str, Any], run_id: str, end: float, elapsed: float
) -> tuple[float, float]:
    """(deadline, elapsed) after one ``status`` answer ``st`` while waiting for run
    ``run_id``: the deadline moves to :data:`RUN_SLACK_S` from now whenever the run's elapsed
    time (the loop's clock: simulated time on a lock-step rig) has grown since the last answer.
    A lock-step rig on a loaded machine runs slower than the wall clock, so a run is given up
    on when it stops progressing, not when the wall clock passes its duration."""
    run = st.get("run") or {}
    if run.get("id") == run_id:
        now_elapsed = float(run.get("elapsed_s", 0.0))
        if now_elapsed > elapsed:
            return max(end, time.monotonic() + RUN_SLACK_S), now_elapsed
    return end, elapsed


def follow_run(
    sock: str | Path, name: str, rows: list[list[float]], comp: str, log: bool = True
) -> dict[str, Any]:
    """Run trajectory ``rows`` (``name``, compensation ``comp``) through the daemon on ``sock``
    and wait for its end (:func:`run_deadline`) and, with ``log``, for its log to be closed by
    the writer (a process at low priority, seconds behind on a loaded machine, or lock-step's
    idle-priority writer). Returns the daemon's answer with the run's ``state`` and
    ``end_reason``; RigError when the run stops progressing or its log is not closed."""
    from cdcr_ctl.runlog.reader import wait_run_closed

    with ControlClient(sock) as c:
        res = c.call("trajectory", name=name, samples=rows, compensation=comp, log=log)
        end = time.monotonic() + res["duration_s"] + RUN_SLACK_S
        elapsed = -1.0
        while time.monotonic() < end:
            st = c.call("status")
            end, elapsed = run_deadline(st, res["run"], end, elapsed)
            done = next((r for r in st["runs"] if r["id"] == res["run"]), None)
            if done is not None:
                log_dir = res.get("log_dir")
                if (
                    log
                    and log_dir
                    and not wait_run_closed(log_dir, max(0.0, end - time.monotonic()))
                ):
                    raise RigError(f"run {name}: its log {log_dir} was not closed")
                return {**res, "state": done["state"], "end_reason": done["end_reason"]}
            time.sleep(POLL_S)
    raise RigError(f"run {name} did not finish: no progress for {RUN_SLACK_S:.0f} s")
