"""A lock-step rig with its control loop in this process, driven by the caller (benchmarks,
tests, sweeps that need no control socket).

:class:`LockstepSession` wires what the daemon wires (model, supervisor, loop, run logs) over a
:class:`~cdcr_ctl.sim.lockstep.rig.LockstepRig`; :meth:`LockstepSession.run` follows one
trajectory (with the daemon's lead-in from the commanded pose) and returns when the loop has
ended it, in simulated time, as fast as the CPU allows.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.control.loop import ControlLoop, LoopConfig, RunInfo
from cdcr_ctl.control.supervisor import Supervisor
from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.writer.factory import RunLogFactory
from cdcr_ctl.sim.lockstep.clock import SETTLE_TIMEOUT_S
from cdcr_ctl.sim.lockstep.placement import Placement
from cdcr_ctl.sim.lockstep.rig import LockstepRig
from cdcr_ctl.sim.simconfig import LoadedSim

#: Longest wall time a run may take per simulated second before it counts as stuck (s/s).
STUCK_WALL_PER_SIM_S = 20.0
#: :meth:`LockstepSession.run` waits for the loop to go idle (:attr:`SimClock.idle`), and looks
#: at the run at least this often (s, wall clock; each look takes the interpreter lock from the
#: loop thread).
RUN_POLL_S = 0.05
#: The loop went idle before it took the run up: look again after this (s, wall clock).
TAKE_UP_WAIT_S = 0.001


class LockstepSession:
    """Rig, model, supervisor and loop of controller config ``ctl`` (file ``ctl_path``) on the
    lock-step world ``loaded``; run logs below ``log_dir``. Enabled and homed on :meth:`open`."""

    def __init__(
        self,
        loaded: LoadedSim,
        ctl: RigConfig,
        ctl_path: str | Path,
        log_dir: str | Path,
        truth_process: bool = True,
        placement: Placement | None = None,
    ) -> None:
        self.cfg = ctl
        self.model = build_model(ctl, source=str(ctl_path))
        # The loop runs on simulated time: a full run-log ring makes it wait for the writer (no
        # row may be dropped: the logs must be the same on every run, whatever the load).
        self.sinks = RunLogFactory.from_config(ctl, ctl_path, base_dir=log_dir, on_full="wait")
        self.rig = LockstepRig.open(
            loaded, ctl, str(ctl_path), truth_process=truth_process, placement=placement
        )
        assert self.rig.drives is not None
        self.drives = self.rig.drives
        attach = getattr(self.model, "attach_attitude", None)
        if attach is not None and self.rig.attitude is not None:
            attach(self.rig.attitude)
        by_cable = {d.cable: d for d in ctl.drives}
        self.supervisor = Supervisor(
            ctl.limits,
            use_tension=ctl.sensors.load_cells is not None,
            use_tracker=ctl.sensors.tracker is not None,
        )
        self.loop = ControlLoop(
            LoopConfig(
                period_s=1.0 / ctl.control.rate_hz,
                counts_per_mm=np.array([by_cable[c.name].counts_per_mm for c in ctl.robot.cables]),
                compensation=ctl.control.compensation,
                cable_velocity_mm_s=ctl.limits.cable_velocity_mm_s,
            ),
            self.model,
            self.drives,
            self.rig.tensions,
            self.rig.tip,
            self.supervisor,
            clock=self.rig.clock,
        )
        self.rig.clock.busy = lambda: self.loop.busy
        self._ended = threading.Event()

    @classmethod
    def open(
        cls,
        loaded: LoadedSim,
        ctl: RigConfig,
        ctl_path: str | Path,
        log_dir: str | Path,
        truth_process: bool = True,
        placement: Placement | None = None,
    ) -> LockstepSession:
        s = cls(loaded, ctl, ctl_path, log_dir, truth_process, placement)
        try:
            s.loop.start()
            s.drives.enable()
            s.loop.drives_reenabled()
            s.loop.pause(True)
            try:
                home = s.drives.home()
            finally:
                s.loop.pause(False)
            s.loop.set_home(home)
            s.settle()
        except BaseException:
            s.close()
            raise
        return s

    def run(
        self, traj: Any, name: str, compensation: str | None = None, log: bool = True
    ) -> RunInfo:
        """Follow ``traj`` (after a lead-in from the commanded pose) and wait until the loop
        ends it; the run's record (``log_dir`` is its run directory when ``log``)."""
        self.settle()  # the run starts from a settled loop: the same cycle on every run
        lead = tj.with_lead_in(self.loop.psi_cmd, traj)
        comp = compensation or self.loop.cfg.compensation
        sink = self.sinks(name, comp) if log else None
        run = self.loop.follow(lead, name, compensation, sink)
        clock = self.rig.clock
        clock.wake()
        limit = time.monotonic() + 60.0 + STUCK_WALL_PER_SIM_S * lead.duration_s
        while run.state == "running" or self.loop.current_run is run:
            if time.monotonic() > limit or not self.loop.running:
                raise RigError(f"lock-step run {name} did not end (state {run.state})")
            # The caller waits on the wall clock; the loop does not.
            if clock.idle.wait(RUN_POLL_S):
                time.sleep(TAKE_UP_WAIT_S)  # idle with the run not ended: not yet taken up
        if sink is not None:
            sink.wait_closed(60.0)
        return run

    def settle(self) -> None:
        """Wait until the loop has taken up every posted command and has no work left
        (:meth:`SimClock.wait_settled`: what the next command does then starts at a simulated
        time set by the commands alone, not by when the loop thread got the CPU)."""
        if not self.rig.clock.wait_settled(SETTLE_TIMEOUT_S):
            raise RigError(f"lock-step loop did not settle within {SETTLE_TIMEOUT_S} s")

    def close(self) -> None:
        self.rig.clock.close()
        self.loop.stop()
        self.rig.close()
        self.sinks.close_spare()

    def __enter__(self) -> LockstepSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["LockstepSession"]
