"""The rig process's planner: lead-ins and jog moves planned in a worker process of their own
(issue #21), so the model work of a run's start never holds the rig process's interpreter lock.

Planning a lead-in runs the model's command (:func:`~cdcr_ctl.daemon.planning.command_path`) on
up to :data:`~cdcr_ctl.daemon.planning.CHECK_SAMPLES` poses in Python: 30-130 ms of CPU at a
run's start on this machine (README, "The control plane cannot stall the loop"), during which
the loop thread of the same process waited for the interpreter lock at every switch interval,
and longer than that inside numpy calls that keep it. Here the rig process's command thread
sends the planning inputs (a few poses, the friction memory) to the worker and waits on a pipe,
which releases the lock; what comes back is a short trajectory (the lead, or the jog move) that
the command thread checks cheaply against the limits before handing it to the loop
(:func:`check_move`).

The worker is spawned (no state shared with the rig process), scheduled SCHED_OTHER (never
real-time, whatever the rig process runs at) and builds its own model from the rig config file,
the same code and file as the rig process's model, so a plan is the one the rig process would
have made. Start it before the rig process raises its priority (:meth:`Planner.start`). A worker
that dies is replaced on the next request; if planning fails there, the caller plans in its own
process (:meth:`Planner.lead` and :meth:`Planner.jog` raise :class:`PlannerUnavailable`).
"""

from __future__ import annotations

import contextlib
import logging
import os
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon.planning import LeadMove, plan_jog, plan_lead
from cdcr_ctl.daemon.workers import one_worker_pool, watch_parent
from cdcr_ctl.errors import RigError

log = logging.getLogger(__name__)

#: Longest wait for one plan (s): ~0.1 s idle, seconds on a loaded machine.
PLAN_TIMEOUT_S = 30.0
#: Pose agreement (rad, bending-vector distance) between a plan's ends and the poses it was asked
#: for: :func:`~cdcr_ctl.control.trajectory.with_lead_in`'s own tolerance (no lead-in is planned
#: across a smaller gap); a move's ends are otherwise the exact poses it was given.
POSE_TOLERANCE_RAD = 1e-6

#: (in the worker) The rig's model, built once by :func:`_init`.
_MODEL: Any = None


class PlannerUnavailable(RigError):
    """The worker could not plan (it died, or did not answer in time): plan in this process."""


def _init(config_path: str, parent_pid: int) -> None:
    """(in the worker) Off real time, a watch on the parent, then the rig's model from its
    config file."""
    global _MODEL
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    watch_parent(parent_pid)
    path = Path(config_path)
    _MODEL = build_model(load_rig_config(path), source=str(path))


def _lead(args: tuple[Any, ...]) -> LeadMove:
    return plan_lead(_MODEL, *args)


def _jog(args: tuple[Any, ...]) -> tuple[np.ndarray, np.ndarray, float, float]:
    traj, speed, peak = plan_jog(_MODEL, *args)
    return np.asarray(traj.t_s), np.asarray(traj.psi), speed, peak


class Planner:
    """Plans in one worker process (see the module docstring)."""

    def __init__(self, config_path: str | Path, timeout_s: float = PLAN_TIMEOUT_S) -> None:
        self.config_path = str(config_path)
        self.timeout_s = timeout_s
        self._pool: ProcessPoolExecutor | None = None
        #: Plans made by the worker, and plans the caller had to make itself.
        self.plans = 0
        self.failures = 0

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = one_worker_pool(_init, (self.config_path, os.getpid()))
        return self._pool

    def start(self) -> Planner:
        """Start the worker now and wait until it has built its model (call before the rig
        process turns real-time: the worker then starts at the ordinary policy)."""
        self._executor().submit(int, 0).result(self.timeout_s * 4)
        return self

    def _call(self, fn: Any, args: tuple[Any, ...]) -> Any:
        try:
            out = self._executor().submit(fn, args).result(self.timeout_s)
        except BrokenProcessPool as exc:
            self._pool = None  # a new worker next time
            self.failures += 1
            raise PlannerUnavailable(f"planner worker died: {exc}") from exc
        except TimeoutError as exc:
            self.failures += 1
            raise PlannerUnavailable(
                f"planner: no answer within PLAN_TIMEOUT_S = {self.timeout_s:g} s"
            ) from exc
        self.plans += 1
        return out

    def lead(
        self,
        psi_now: np.ndarray,
        q_cmd_now_mm: np.ndarray | None,
        first_psi: np.ndarray,
        mode: str,
        cable_velocity_mm_s: float,
        bend_limit_rad: float,
        measured_N: np.ndarray | None = None,
        state: Any = None,
    ) -> LeadMove:
        """:func:`~cdcr_ctl.daemon.planning.plan_lead` in the worker, checked here
        (:func:`check_move`)."""
        args = (psi_now, q_cmd_now_mm, first_psi, mode, cable_velocity_mm_s, measured_N, state)
        move: LeadMove = self._call(_lead, args)
        check_move(move.lead, psi_now, first_psi, bend_limit_rad, "lead-in")
        return move

    def jog(
        self,
        start: np.ndarray,
        goal: np.ndarray,
        speed_rad_s: float,
        mode: str,
        cable_velocity_mm_s: float,
        bend_limit_rad: float,
    ) -> tuple[tj.Trajectory, float, float]:
        """:func:`~cdcr_ctl.daemon.planning.plan_jog` in the worker, checked here."""
        args = (start, goal, speed_rad_s, mode, cable_velocity_mm_s)
        t, psi, speed, peak = self._call(_jog, args)
        traj = tj.Trajectory(t, psi, f"jog at {speed:.4g} rad/s", "<jog>")
        check_move(traj, start, goal, bend_limit_rad, "jog")
        return traj, speed, peak

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None


def check_move(
    traj: tj.Trajectory,
    start: np.ndarray,
    goal: np.ndarray,
    bend_limit_rad: float,
    what: str,
) -> None:
    """The cheap checks of a move planned elsewhere, vectorised (microseconds for a lead-in):
    finite, times from 0 and increasing, every bend within ``[0, bend_limit_rad]``, starting at
    ``start`` and ending at ``goal`` (within :data:`POSE_TOLERANCE_RAD`). The velocity limit is
    the supervisor's, checked every cycle. Raises :class:`RigError` naming what failed."""
    t, psi = np.asarray(traj.t_s), np.asarray(traj.psi)
    start = np.asarray(start, dtype=float).reshape(psi.shape[1:])
    goal = np.asarray(goal, dtype=float).reshape(psi.shape[1:])
    problems = []
    if not (np.isfinite(t).all() and np.isfinite(psi).all()):
        problems.append("not finite")
    elif t[0] != 0.0 or (len(t) > 1 and not bool(np.all(np.diff(t) > 0))):
        problems.append("times not increasing from 0")
    elif not bool(np.all((psi[..., 0] >= 0) & (psi[..., 0] <= bend_limit_rad))):
        problems.append(f"bend outside [0, {bend_limit_rad}] rad (limits.bend_rad)")
    elif _gap(psi[0], start) > POSE_TOLERANCE_RAD:
        problems.append("does not start at the commanded pose")
    elif _gap(psi[-1], goal) > POSE_TOLERANCE_RAD:
        problems.append("does not end at the pose asked for")
    if problems:
        raise RigError(f"planner: the {what} planned is refused: {problems[0]}")


def _gap(a: np.ndarray, b: np.ndarray) -> float:
    """Largest bending-vector distance (rad) between two poses (S, 2)."""
    return float(np.max(np.linalg.norm(tj.bend_vectors(a) - tj.bend_vectors(b), axis=-1)))


__all__ = ["PLAN_TIMEOUT_S", "Planner", "PlannerUnavailable", "check_move"]
