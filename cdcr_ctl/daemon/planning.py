"""Moves the daemon plans between runs: lead-ins, compensation-mode switches, the start-up pose.

Cable velocity is the supervisor's limit, so every plan here is checked in cable space, through
the model's command of the mode the run will use (``q_command``), not only its ideal kinematics:

- **Mode switch.** A run whose compensation differs from the mode in force steps the command by
  the difference of the two deltas; the loop takes the step into its cable offset and ramps it
  out at ``OFFSET_RAMP_FRACTION`` of the velocity limit (:mod:`cdcr_ctl.control.loop`). If that
  ramp overlapped the run's own motion the two would add up past the limit (the trip of
  ``circle-off-identified`` in issue #21), so the plan holds still until the ramp is done.
- **Lead-in.** The move from the commanded pose to the run's first sample keeps its fastest
  cable, in the run's own mode, within ``LEAD_IN_CABLE_FRACTION`` of the limit.
- **Start-up pose.** A daemon started with the arm bent reads the drives' positions and fits the
  pose whose ideal cable displacements match them (least squares in bending vectors), so the
  loop holds, and later ramps, from where the arm is.

Units: rad (pose), mm (cable), s, mm/s.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.control.loop import OFFSET_RAMP_FRACTION
from cdcr_ctl.model.port import RobotModelPort

#: The lead-in move keeps its fastest cable within this fraction of the velocity limit (the rest
#: is room for the compensation's own motion and the loop's timing).
LEAD_IN_CABLE_FRACTION = 0.5
#: Extra hold after a mode-switch ramp (s): a few cycles of margin for the loop to finish it.
SWITCH_MARGIN_S = 0.05
#: A command step smaller than this (mm) needs no hold (friction-state and rounding noise).
SWITCH_TOLERANCE_MM = 1e-3
#: Samples of a planned move checked for cable speed at most (evenly spread; the move is a
#: raised cosine, smooth on this scale).
CHECK_SAMPLES = 400


class Chain:
    """A setpoint source: ``first``, then ``then`` (its times shifted by ``first``'s duration).

    For long trajectories (a 10^6-row file) the lead-in goes in front this way instead of by
    concatenating arrays: no copy of the long one in the loop's process."""

    def __init__(self, first: tj.Trajectory, then: Any) -> None:
        self.first, self.then = first, then
        self._t1 = first.duration_s
        self.name, self.source = then.name, then.source

    @property
    def duration_s(self) -> float:
        return self._t1 + self.then.duration_s

    def sample(self, t_s: float) -> np.ndarray:
        if t_s < self._t1:
            return self.first.sample(t_s)
        return self.then.sample(t_s - self._t1)


@dataclass(frozen=True)
class LeadInPlan:
    """What :func:`plan_lead_in` decided: hold ``hold_s`` for the mode switch to ramp out, then
    a move at ``speed_rad_s`` whose fastest cable runs ``peak_mm_s`` (in the run's mode)."""

    trajectory: Any  # tj.Trajectory, or a Chain for a long one
    hold_s: float
    speed_rad_s: float
    peak_mm_s: float


def command_path(
    model: RobotModelPort,
    psi: np.ndarray,
    mode: str,
    measured_N: np.ndarray | None = None,
    state: Any = None,
) -> np.ndarray:
    """(N, K) commanded cable displacements (mm) along poses ``psi`` (N, S, 2) in ``mode``, with
    the friction memory carried along the path from ``state`` (copied: the loop's memory, so a
    path that reverses the last motion shows the friction flip) or a fresh one."""
    state = model.new_state() if state is None else copy.deepcopy(state)
    out = np.empty((len(psi), model.n_cables))
    for i, p in enumerate(psi):
        q_nom = model.q_nominal(p)
        out[i] = model.q_command(p, q_nom, state, mode, measured_N if mode == "measured" else None)
    return out


def peak_cable_speed(
    model: RobotModelPort,
    traj: tj.Trajectory,
    mode: str,
    measured_N: np.ndarray | None = None,
    state: Any = None,
) -> float:
    """Fastest cable speed (mm/s) of ``traj`` commanded in ``mode`` (at most
    :data:`CHECK_SAMPLES` samples, evenly spread, so a long move is checked quickly)."""
    if traj.n_samples < 2:
        return 0.0
    idx = np.unique(np.linspace(0, traj.n_samples - 1, CHECK_SAMPLES).astype(int))
    q = command_path(model, traj.psi[idx], mode, measured_N, state)
    dt = np.diff(traj.t_s[idx])
    return float(np.max(np.abs(np.diff(q, axis=0)) / dt[:, None]))


def switch_hold_s(step_mm: np.ndarray, cable_velocity_mm_s: float) -> float:
    """How long the loop's offset ramp takes to take out a command step ``step_mm`` (K,) (s),
    plus :data:`SWITCH_MARGIN_S`; 0 for no step."""
    worst = float(np.max(np.abs(step_mm))) if len(step_mm) else 0.0
    if worst <= SWITCH_TOLERANCE_MM:
        return 0.0
    return worst / (OFFSET_RAMP_FRACTION * cable_velocity_mm_s) + SWITCH_MARGIN_S


@dataclass(frozen=True)
class LeadMove:
    """What :func:`plan_lead` decided, before the trajectory is put after it: ``lead`` holds
    ``hold_s`` at the commanded pose (a mode switch's ramp) and then moves to the trajectory's
    first pose at ``speed_rad_s`` (its fastest cable ``peak_mm_s`` in the run's mode); one
    sample when neither is needed."""

    lead: tj.Trajectory
    hold_s: float
    speed_rad_s: float
    peak_mm_s: float


def plan_lead(
    model: RobotModelPort,
    psi_now: np.ndarray,
    q_cmd_now_mm: np.ndarray | None,
    first_psi: np.ndarray,
    mode: str,
    cable_velocity_mm_s: float,
    measured_N: np.ndarray | None = None,
    state: Any = None,
) -> LeadMove:
    """The hold and lead-in move from ``psi_now`` (S, 2) to ``first_psi`` (S, 2), each within
    the velocity limit: the model work of :func:`plan_lead_in` (the command path of up to
    :data:`CHECK_SAMPLES` poses in ``mode``), done apart from the trajectory so that it can run
    in another process (:mod:`cdcr_ctl.daemon.planner`). Arguments as :func:`plan_lead_in`."""
    psi_now = np.asarray(psi_now, dtype=float).reshape(-1, 2)
    first_psi = np.asarray(first_psi, dtype=float).reshape(-1, 2)
    hold_s = 0.0
    if q_cmd_now_mm is not None:
        q_new = command_path(model, psi_now[None], mode, measured_N, state)[0]
        hold_s = switch_hold_s(np.asarray(q_cmd_now_mm) - q_new, cable_velocity_mm_s)
    v_allowed = LEAD_IN_CABLE_FRACTION * cable_velocity_mm_s
    speed = tj.LEAD_IN_SPEED_RAD_S
    # The move alone (the trajectory's first sample as its goal): the long trajectory itself is
    # never copied here.
    head = tj.Trajectory([0.0], first_psi[None])
    lead = tj.with_lead_in(psi_now, head, speed_rad_s=speed)
    peak = 0.0
    if lead is not head:
        for _ in range(3):
            m = tj.move(psi_now, first_psi, speed)
            peak = peak_cable_speed(model, m, mode, measured_N, state)
            if peak <= v_allowed:
                break
            speed *= 0.98 * v_allowed / peak
        lead = tj.with_lead_in(psi_now, head, speed_rad_s=speed)
    if hold_s > 0.0:
        lead = _hold_first(lead, psi_now, hold_s)
    return LeadMove(lead, hold_s, speed, peak)


def attach_lead(move: LeadMove, traj: Any) -> LeadInPlan:
    """``traj`` after ``move``'s lead (which ends on ``traj``'s first pose): concatenated, or
    chained in front of a long trajectory (:class:`Chain`: never copied). No model work."""
    lead, hold_s, speed, peak = move.lead, move.hold_s, move.speed_rad_s, move.peak_mm_s
    if lead.n_samples == 1:  # neither a hold nor a move
        return LeadInPlan(traj, hold_s, speed, peak)
    if traj.n_samples > tj.LIST_SAMPLES:
        # The lead ends on the trajectory's first sample; the trajectory starts there.
        return LeadInPlan(Chain(lead, traj), hold_s, speed, peak)
    t = np.concatenate((lead.t_s[:-1], traj.t_s + lead.t_s[-1]))
    psi = np.concatenate((lead.psi[:-1], traj.psi))
    return LeadInPlan(tj.Trajectory(t, psi, traj.name, traj.source), hold_s, speed, peak)


def plan_lead_in(
    model: RobotModelPort,
    psi_now: np.ndarray,
    q_cmd_now_mm: np.ndarray | None,
    traj: tj.Trajectory,
    mode: str,
    cable_velocity_mm_s: float,
    measured_N: np.ndarray | None = None,
    state: Any = None,
) -> LeadInPlan:
    """``traj`` preceded by a hold (for a mode switch's ramp) and a lead-in move, each within the
    velocity limit (:func:`plan_lead`, then :func:`attach_lead`).

    ``q_cmd_now_mm``: the loop's last command (its offset included); the step the loop will ramp
    out is its difference from ``mode``'s command at ``psi_now``. The lead-in move's speed is
    scaled down from ``tj.LEAD_IN_SPEED_RAD_S`` until its fastest cable, commanded in ``mode``,
    is within ``LEAD_IN_CABLE_FRACTION`` of the limit (cable speed is proportional to the
    move's speed: one rescale, then checked again). ``state``: the loop's friction memory (see
    :func:`command_path`); None plans from a fresh one.
    """
    move = plan_lead(
        model,
        psi_now,
        q_cmd_now_mm,
        traj.psi[0],
        mode,
        cable_velocity_mm_s,
        measured_N,
        state,
    )
    return attach_lead(move, traj)


def plan_jog(
    model: RobotModelPort,
    start: np.ndarray,
    goal: np.ndarray,
    speed_rad_s: float,
    mode: str,
    cable_velocity_mm_s: float,
) -> tuple[tj.Trajectory, float, float]:
    """A jog move from ``start`` to ``goal`` (S, 2) at ``speed_rad_s``, slowed so its fastest
    cable commanded in ``mode`` stays within ``LEAD_IN_CABLE_FRACTION`` of the velocity limit;
    returns (move, speed used, fastest cable at the speed asked, mm/s)."""
    traj = tj.move(start, goal, speed_rad_s=speed_rad_s)
    v_allowed = LEAD_IN_CABLE_FRACTION * cable_velocity_mm_s
    peak = peak_cable_speed(model, traj, mode)
    speed = speed_rad_s
    if peak > v_allowed:
        speed *= 0.98 * v_allowed / peak
        traj = tj.move(start, goal, speed_rad_s=speed)
    return traj, speed, peak


def _hold_first(traj: tj.Trajectory, psi_now: np.ndarray, hold_s: float) -> tj.Trajectory:
    """``traj`` preceded by ``hold_s`` of standing at ``psi_now`` (its first pose)."""
    t = np.concatenate(([0.0], traj.t_s + hold_s))
    psi = np.concatenate((psi_now[None], traj.psi))
    return tj.Trajectory(t, psi, traj.name, traj.source)


def estimate_pose(
    model: RobotModelPort,
    q_mm: np.ndarray,
    bend_limit_rad: float,
    psi_guess: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """The pose (S, 2) whose ideal cable displacements best match ``q_mm`` (K,), and the largest
    cable residual (mm). Solved in bending vectors (no singularity at straight), bend within
    ``bend_limit_rad`` per segment."""
    S = model.n_segments
    x0 = (
        np.zeros(2 * S)
        if psi_guess is None
        else tj.bend_vectors(np.asarray(psi_guess, float).reshape(S, 2)).ravel()
    )
    q_mm = np.asarray(q_mm, dtype=float)

    def psi_of(x: np.ndarray) -> np.ndarray:
        v = x.reshape(S, 2)
        return np.stack((np.hypot(v[:, 0], v[:, 1]), np.arctan2(v[:, 1], v[:, 0])), axis=-1)

    def residual(x: np.ndarray) -> np.ndarray:
        return model.q_nominal(psi_of(x)) - q_mm

    if not np.any(q_mm):
        return np.zeros((S, 2)), 0.0
    b = bend_limit_rad
    sol = least_squares(residual, x0, bounds=(-b * np.ones(2 * S), b * np.ones(2 * S)))
    psi = psi_of(sol.x)
    # Keep each bend within the limit (the box bounds allow sqrt(2) b on a diagonal).
    psi[:, 0] = np.minimum(psi[:, 0], b)
    res = float(np.max(np.abs(model.q_nominal(psi) - q_mm)))
    return psi, res if math.isfinite(res) else math.inf


__all__ = [
    "LEAD_IN_CABLE_FRACTION",
    "LeadInPlan",
    "LeadMove",
    "attach_lead",
    "command_path",
    "estimate_pose",
    "peak_cable_speed",
    "plan_jog",
    "plan_lead",
    "plan_lead_in",
    "switch_hold_s",
]
