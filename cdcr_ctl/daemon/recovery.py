"""The daemon's way out of every state a rig can be left in (issue #21).

- :func:`stop_now`: ``stop`` through the loop's :class:`~cdcr_ctl.control.loop.StopFlag`,
  answered once the loop acted (no lock, no queue);
- :func:`adopt_start_pose`: a daemon started with the arm bent holds the pose the drives report
  (fitted through the model) instead of commanding it straight;
- :func:`straighten`: before homing on the current position, a bent arm is brought straight at
  the lead-in's cable speed;
- :func:`drive_status`: feedback older than the bus's feedback timeout is shown as stale, not as
  the state it last had;
- :func:`reset_fault`: clears a latched fault, re-opening the bus when the drives stopped
  answering (a lost or restarted bus).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.control.ports import DriveState
from cdcr_ctl.control.supervisor import Reaction, Supervisor
from cdcr_ctl.daemon.planning import estimate_pose, plan_lead_in
from cdcr_ctl.daemon.rig import Rig
from cdcr_ctl.daemon.rigshare import STOP_ACK_TIMEOUT_S
from cdcr_ctl.errors import RigError

log = logging.getLogger(__name__)

#: Longest wait for the quick stop's frame to reach the bus tap through the traffic log's
#: writer thread (s): a hundred of its drain periods (a loaded machine may starve the thread).
BUS_TAP_WAIT_S = 2.0
#: Longest wait at start-up for every drive's first feedback (s).
START_FEEDBACK_TIMEOUT_S = 10.0
#: A cable further than this from straight (mm) is brought straight before homing.
STRAIGHT_TOLERANCE_MM = 0.05
#: Slack beyond a straightening move's duration before homing gives up on it (s).
STRAIGHTEN_SLACK_S = 10.0
#: Tries of the fault reset after the bus was re-opened.
REOPEN_RESET_ATTEMPTS = 3
#: Feedback older than this many feedback timeouts is shown stale.
STALE_FACTOR = 1.0


def stop_now(d: Rig, reaction: Reaction) -> dict[str, Any]:
    """Raise the loop's stop flag and wait (bounded) for the cycle that acted on it.

    Returns ``acted_cycle`` (the loop cycle that sent the stop), ``cycles_waited`` (how many
    cycles after the request) and ``bus``: the stop timed on the CAN traffic log
    (:class:`~cdcr_ctl.daemon.bustap.StopBusTap`: request arrival to the first quick-stop
    frame, SYNCs in between; None without a traffic log or for a halt). A loop that is not
    running cannot act: the drives are stopped directly.
    """
    arrived = time.time()
    flag = d.loop.stop_flag
    cycle0 = d.loop.counters.cycles
    seq = flag.request(reaction)
    return await_stop(d, reaction, seq, cycle0, arrived)


def await_stop(
    d: Rig, reaction: Reaction, seq: int, cycle0: int, arrived_wall_s: float
) -> dict[str, Any]:
    """The second half of :func:`stop_now`, for a flag raised elsewhere (the daemon's front
    process writes the shared-memory flag itself): request ``seq`` arrived at
    ``arrived_wall_s`` (``time.time()``) in loop cycle ``cycle0``; wait for the cycle that
    acted, stop the drives directly if the loop is not running, and time it on the bus."""
    loop = d.loop
    flag = loop.stop_flag
    tap = getattr(d, "bus_tap", None)
    if tap is not None:
        tap.arm(arrived_wall_s)
    end = time.monotonic() + STOP_ACK_TIMEOUT_S
    acted: int | None = flag.acted_cycle(seq)
    while acted is None and loop.running and time.monotonic() < end:
        time.sleep(loop.cfg.period_s / 4)
        acted = flag.acted_cycle(seq)
    if acted is None and reaction is Reaction.QUICK_STOP:
        d.io.drives.quick_stop()
    logging_traffic = bool(getattr(getattr(d.io.drives, "group", None), "traffic_logging", False))
    bus = _bus_timing(tap, loop.cfg.period_s, reaction, acted is not None and logging_traffic)
    if acted is None:
        return {"acted_cycle": None, "cycles_waited": None, "bus": bus}
    return {"acted_cycle": acted, "cycles_waited": acted - cycle0, "bus": bus}


def _bus_timing(tap: Any, period_s: float, reaction: Reaction, wait: bool) -> dict[str, Any] | None:
    """The tap's timing of the stop. The traffic log reaches the tap from its writer thread
    (:class:`~cdcr_ctl.drives.group.traffic.DeferredTrafficLog`, every ``DRAIN_PERIOD_S``):
    with ``wait`` (a traffic log is running and the loop acted) and a quick stop, wait for its
    frame to arrive, bounded by :data:`BUS_TAP_WAIT_S`."""
    if tap is None:
        return None
    bus = tap.result(period_s)
    if bus is not None or not wait or reaction is not Reaction.QUICK_STOP:
        return bus
    end = time.monotonic() + BUS_TAP_WAIT_S
    while bus is None and time.monotonic() < end:
        time.sleep(period_s)
        bus = tap.result(period_s)
    return bus


def hold_tracker_check(supervisor: Supervisor) -> Callable[[], None]:
    """Switch the tracker-versus-model check off until the returned function restores it (the
    model tip of a pose not yet known must not trip the rig)."""
    was = supervisor.use_tracker
    supervisor.use_tracker = False

    def restore() -> None:
        supervisor.use_tracker = was

    return restore


def _q_act_mm(d: Rig, fb: Sequence[DriveState]) -> np.ndarray:
    counts = np.array([f.position_counts for f in fb], dtype=float)
    return (counts - d.loop.home_counts) / d.loop.cfg.counts_per_mm


def adopt_start_pose(d: Rig, restore: Callable[[], None]) -> None:
    """(start-up thread) Wait for every drive's feedback, fit the pose it shows and have the
    loop hold there; then restore the tracker check."""
    try:
        end = time.monotonic() + START_FEEDBACK_TIMEOUT_S
        fb = d.io.drives.feedback()
        while any(f.state == "UNKNOWN" for f in fb) and time.monotonic() < end:
            time.sleep(0.01)
            fb = d.io.drives.feedback()
        if any(f.state == "UNKNOWN" for f in fb):
            log.warning("start-up: no feedback from every drive; holding the straight pose")
            return
        q = _q_act_mm(d, fb)
        psi, residual = estimate_pose(d.model, q, d.cfg.limits.bend_rad)
        if np.any(psi[:, 0] > 1e-4):
            log.info(
                "start-up: the arm is bent (theta %s rad); holding there (fit residual %.3f mm)",
                np.round(psi[:, 0], 4).tolist(),
                residual,
            )
        d.loop.adopt_pose(psi)
        d._wait_cycles(3)
    except Exception:
        log.exception("start-up pose: failed; holding the straight pose")
    finally:
        restore()


def straighten(d: Rig) -> None:
    """Bring the arm straight (ψ = 0, no offset) at the lead-in's cable speed before homing.

    Nothing to do when every cable is within :data:`STRAIGHT_TOLERANCE_MM` of straight. Raises
    :class:`RigError` if the move does not complete (a stop, a trip)."""
    q_act = _q_act_mm(d, d.io.drives.feedback())
    q_straight = d.model.q_nominal(np.zeros((d.model.n_segments, 2)))
    if np.max(np.abs(q_act - q_straight)) <= STRAIGHT_TOLERANCE_MM and not np.any(
        d.loop.psi_cmd[:, 0]
    ):
        return
    goal = tj.Trajectory([0.0], np.zeros((1, d.model.n_segments, 2)), "straighten", "<home>")
    plan = plan_lead_in(
        d.model,
        d.loop.psi_cmd,
        d.loop.q_cmd,
        goal,
        "off",
        d.cfg.limits.cable_velocity_mm_s,
    )
    traj = plan.trajectory
    if traj.n_samples < 2:  # already at the pose: the offset alone ramps out in a short hold
        traj = tj.Trajectory([0.0, 0.05], np.zeros((2, d.model.n_segments, 2)), "straighten")
    run = d.loop.follow(traj, "straighten before homing", "off", None)
    end = time.monotonic() + traj.duration_s + STRAIGHTEN_SLACK_S
    while run.state == "running" and time.monotonic() < end:
        time.sleep(0.02)
    if run.state != "completed":
        raise RigError(f"homing: straightening the arm first ended {run.state}: {run.end_reason}")


def drive_status(cfg: RigConfig, fb: Sequence[DriveState]) -> list[dict[str, Any]]:
    """Per drive: position, state, fault; feedback older than the bus's feedback timeout shows
    ``state: STALE`` with the last state and its age (a lost bus is not OPERATION ENABLED)."""
    timeout_s = cfg.can.feedback_timeout_s or 3 * cfg.can.sync_period_s
    out = []
    for c, f in zip(cfg.robot.cables, fb, strict=False):
        row: dict[str, Any] = {
            "cable": c.name,
            "position_counts": f.position_counts,
            "state": f.state,
            "fault": f.fault,
        }
        age = float(getattr(f, "age_s", 0.0))
        if f.state != "UNKNOWN" and age > STALE_FACTOR * timeout_s:
            row.update(state="STALE", last_state=f.state, age_s=round(age, 3))
        out.append(row)
    return out


def reset_fault(d: Rig) -> dict[str, Any]:
    """Clear the drives' faults and the supervisor's latch; when the drives do not answer (a
    lost bus, a restarted rig) re-open the bus and boot them again first."""
    drives = d.io.drives
    reopened = False
    notes: list[str] = []
    try:
        # A drive that rebooted mid-run is reconfigured (its SDO set) before it may be enabled.
        notes = list(drives.reset_faults() or [])
    except RigError as exc:
        reopen = getattr(drives, "reopen", None)
        if reopen is None:
            raise
        log.warning("reset-fault: %s; re-opening the bus", exc)
        d.loop.pause(True)
        try:
            reopen()
        finally:
            d.loop.pause(False)
        reopened = True
        # Freshly booted drives may miss a heartbeat or two while the bus settles.
        for attempt in range(REOPEN_RESET_ATTEMPTS):
            try:
                notes = list(drives.reset_faults() or [])
                break
            except RigError:
                if attempt == REOPEN_RESET_ATTEMPTS - 1:
                    raise
                time.sleep(0.5)
    sensors = _reopen_stale_sensors(d) if reopened else []
    d.supervisor.reset()
    return {
        "fault": None,
        "bus_reopened": reopened,
        "sensors_reopened": sensors,
        "reconfigured": notes,
    }


def _reopen_stale_sensors(d: Rig) -> list[str]:
    """After a lost bus the rest of the rig may have gone and come back too: re-open a load-cell
    port whose samples are older than the sensor timeout, and wait (bounded) for fresh ones."""
    out: list[str] = []
    limit = d.cfg.limits.sensor_timeout_s
    tensions = d.io.tensions
    _, age = tensions.latest()
    if np.any(np.isfinite(age) & (age > limit)) and hasattr(tensions, "reopen"):
        log.warning("reset-fault: load cells silent for %.1f s; re-opening", float(np.max(age)))
        tensions.reopen()
        out.append("load_cells")
        end = time.monotonic() + START_FEEDBACK_TIMEOUT_S
        while time.monotonic() < end and np.any(tensions.latest()[1] > limit):
            time.sleep(0.02)
    tip = d.io.tip
    _, tip_age = tip.latest()
    if math.isfinite(tip_age) and tip_age > limit and hasattr(tip, "reopen"):
        log.warning("reset-fault: tracker silent for %.1f s; re-connecting", tip_age)
        tip.reopen()
        out.append("tracker")
        end = time.monotonic() + START_FEEDBACK_TIMEOUT_S
        while time.monotonic() < end and not tip.latest()[1] <= limit:
            time.sleep(0.02)
    return out
