"""The soak's verdict (``benchmarks/soak.py``), from the record of its runs.

Each run of a soak is one :class:`SoakRun`: its name, how it ended (``completed``, ``tripped``,
...), the fault injected into it (None: none) and the daemon's end reason. The soak does not inject
a fault into the first run after a recovery (the rig was just reset and re-enabled), so that run
says whether the rig can work again.

The verdict fails (each rule names what broke it) on:

- ``unexpected trip``: a run without an injected fault that did not complete;
- ``no completed run after recovery``: the first run after a fault's recovery did not complete,
  or the soak ended with a recovery no run followed;
- ``lockout``: :data:`LOCKOUT_RUNS` or more runs in a row, none with an injected fault, that did
  not complete (the rig can no longer run at all, as after a recovery that left a cable slack);
- and the checks the soak counts itself (:func:`count_failures`): samples lost or log gaps, a
  fault missed, not made safe or not recovered, memory growth, a dead daemon, recovery errors.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

#: Runs in a row without an injected fault that fail: the rig is locked out.
LOCKOUT_RUNS = 3
#: Largest growth of the daemon's RSS between the baseline and the end (%).
RSS_GROWTH_LIMIT_PCT = 10.0


@dataclass(frozen=True)
class SoakRun:
    """One run of the soak: ``state`` as the daemon's run history says, ``fault`` the injected
    fault's key (None: none), ``after_recovery`` whether it was the first run after one."""

    name: str
    state: str
    fault: str | None
    end_reason: str = ""
    after_recovery: bool = False


def run_failures(runs: list[SoakRun], recovery_pending: bool = False) -> list[str]:
    """What the run record breaks (see the module); ``recovery_pending``: a fault was
    recovered from after the last run (no run followed it)."""
    out: list[str] = []
    streak: list[SoakRun] = []
    for run in runs:
        ok = run.state == "completed"
        if run.fault is None and not ok:
            out.append(f"unexpected trip: {run.name} {run.state} ({run.end_reason})")
        if run.after_recovery and not ok:
            out.append(f"no completed run after recovery: {run.name} {run.state}")
        if run.fault is None and not ok:
            streak.append(run)
        elif ok:  # a run with an injected fault that trips neither ends nor extends a streak
            streak = _lockout(streak, out)
    _lockout(streak, out)
    if recovery_pending:
        out.append("no completed run after recovery: the soak ended before one ran")
    return out


def _lockout(streak: list[SoakRun], out: list[str]) -> list[SoakRun]:
    if len(streak) >= LOCKOUT_RUNS:
        reasons = sorted({r.end_reason.split(" ")[0].rstrip(":") for r in streak})
        out.append(
            f"lockout: {len(streak)} runs in a row ({streak[0].name}..{streak[-1].name}) failed"
            f" with no fault injected: {', '.join(reasons)[:200]}"
        )
    return []


def count_failures(out: dict[str, Any]) -> list[str]:
    """What the soak's own counts break: samples, log gaps, faults missed, unsafe or not
    recovered, memory growth, the daemon's end, recovery errors."""
    bad: list[str] = []
    if out["samples_expected"] != out["samples_logged"] or out["log_gaps"]:
        bad.append(
            f"log: {out['samples_logged']}/{out['samples_expected']} samples,"
            f" {out['log_gaps']} gaps"
        )
    if out["faults_missed"]:
        bad.append(f"faults missed: {out['faults_missed']}")
    n = out["faults_injected"]
    if not out["faults_safe"] == out["faults_tripped"] == n:
        bad.append(
            f"faults: {n} injected, {out['faults_tripped']} tripped, {out['faults_safe']} safe"
        )
    if out["faults_recovered"] != n:
        bad.append(f"faults: {n} injected, {out['faults_recovered']} recovered")
    if out.get("rss_growth_pct", 0.0) > RSS_GROWTH_LIMIT_PCT:
        bad.append(f"memory: RSS grew {out['rss_growth_pct']} %")
    if not out.get("daemon_alive", False):
        bad.append("daemon not alive at the end")
    if out["recovery_errors"]:
        bad.append(f"recovery errors: {out['recovery_errors'][:3]}")
    return bad


def verdict(out: dict[str, Any], runs: list[SoakRun], recovery_pending: bool = False) -> list[str]:
    """Every failure of the soak (empty: it passed)."""
    return count_failures(out) + run_failures(runs, recovery_pending)


__all__ = ["LOCKOUT_RUNS", "SoakRun", "count_failures", "run_failures", "verdict"]
