"""The daemon's status: the ``status`` command (drives, sensors, supervisor, loop, runs), what the
layers below the supervisor latched, and the one-line status for systemd.

:class:`StatusCommands` builds them from the daemon's narrow :class:`~cdcr_ctl.daemon.rig.Rig`
view (it never imports the daemon).
"""

from __future__ import annotations

import math
from typing import Any

from cdcr_ctl.control.supervisor import Trip
from cdcr_ctl.daemon import recovery
from cdcr_ctl.daemon.rig import Rig


class StatusCommands:
    """Status of ``rig``: the ``status`` command (:attr:`handlers`) and the systemd line."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.handlers = {"status": self.status}

    def status(self, args: Any) -> dict[str, Any]:
        rig = self.rig
        fb = rig.io.drives.feedback()
        force, force_age = rig.io.tensions.latest()
        tip, tip_age = rig.io.tip.latest()
        trip = rig.supervisor.trip
        snap = rig.loop.snapshot()
        run = snap.pop("run")
        return {
            "state": rig.state,
            "rig": rig.cfg.name,
            "design": rig.cfg.design,
            "config": str(rig.config_path),
            "enabled": rig.enabled,
            "homed": rig.homed,
            "compensation": rig.loop.cfg.compensation,
            "drives": recovery.drive_status(rig.cfg, fb),
            "tension_N": [None if not math.isfinite(v) else round(float(v), 3) for v in force],
            "tension_age_s": [
                None if not math.isfinite(v) else round(float(v), 4) for v in force_age
            ],
            "tip_mm": [None if not math.isfinite(v) else round(float(v), 3) for v in tip],
            "tip_age_s": None if not math.isfinite(tip_age) else round(tip_age, 4),
            "fault": None if trip is None else _trip_dict(trip),
            "trips": [_trip_dict(t) for t in rig.supervisor.history[-20:]],
            "safety": self.safety(),
            "run": run,
            "runs": [r.__dict__ for r in rig.loop.history[-10:]],
            "loop": snap,
            # A manual log, or the running run's own log (where rows go now).
            "logging": rig._manual_sink is not None
            or bool(run and run.get("state") == "running" and run.get("log_dir")),
            "log_dir": _log_dir(rig._manual_sink, run),
            "joystick": None if rig._session is None else rig._session.status(),
        }

    def safety(self) -> dict[str, Any]:
        """What the layers below the supervisor latched: the drive group's first fault with the
        SYNC counts when it was latched and when the quick stop went out, and a sensor link
        that failed (each only when the I/O offers it)."""
        rig = self.rig
        out: dict[str, Any] = {"later_trips": rig.supervisor.later_trips}
        group = getattr(rig.io.drives, "group", None)
        if group is not None:
            fault = group.fault()
            out["drives"] = {
                "sync_count": group.sync_count,
                "fault": None if fault is None else fault.text,
                # the faulted drive's 0x603F and 0x1003, read after the fault ('' until then)
                "diagnosis": None if fault is None else getattr(fault, "diagnosis", ""),
                "fault_at_sync": group.fault_at_sync,
                "quick_stop_at_sync": group.quick_stop_at_sync,
                "traffic_log_failure": getattr(group, "traffic_failure", None),
            }
        sampler = getattr(rig.io.tensions, "sampler", None)
        if sampler is not None:
            failure = getattr(sampler, "failure", None)
            out["load_cells"] = {"failure": None if failure is None else str(failure)}
        tracker = getattr(rig.io.tip, "tracker", None)
        if tracker is not None:
            failure = getattr(tracker, "failure", None)
            out["tracker"] = {"failure": None if failure is None else str(failure)}
        return out

    def line(self) -> str:
        """One line for systemd's status: state, drives, the running run, a trip."""
        rig = self.rig
        run = rig.loop.snapshot()["run"]
        trip = rig.supervisor.trip
        parts = [rig.state, "enabled" if rig.enabled else "disabled"]
        if run:
            parts.append(f"run {run['name']} {run['elapsed_s']:.1f}/{run['duration_s']:.1f} s")
        if trip:
            parts.append(f"trip {trip.cause}")
        return ", ".join(parts)


def _log_dir(manual: Any, run: dict[str, Any] | None) -> str | None:
    """The run directory rows are written to now: a manual log's, else the running run's."""
    if manual is not None:
        return str(getattr(manual, "run_dir", "")) or None
    if run and run.get("state") == "running":
        return run.get("log_dir") or None
    return None


def _trip_dict(t: Trip) -> dict[str, Any]:
    return {
        "cause": t.cause,
        "reaction": t.reaction.name,
        "detail": t.detail,
        "t_s": round(t.t_s, 4),
    }
