"""``cdcr-ctl sim --lockstep``: the simulated rig and the daemon in one process, on simulated time.

The daemon is the production one (:class:`~cdcr_ctl.daemon.service.Daemon`: control socket,
supervisor, loop, run logs); its I/O is the controller's protocol code on the lock-step rig
(:class:`~cdcr_ctl.sim.lockstep.rig.LockstepRig`) and its loop runs on the rig's simulated clock,
as fast as the CPU allows, only while it has work. Clients (``cdcr-ctl enable``, ``trajectory``,
``experiments``) talk to it as to any daemon.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path
from typing import Any

import click

from cdcr_ctl.sim.lockstep.clock import SETTLE_TIMEOUT_S
from cdcr_ctl.sim.lockstep.placement import Placement

#: Commands that wait for the lock-step loop to settle before they act (see ``settle`` below).
SETTLE_BEFORE = ("trajectory", "joystick", "jog", "compensation")


def serve_lockstep(
    sim_config: str | Path,
    ctl_config: str | Path,
    socket_path: str | None,
    placement: Placement | None = None,
) -> str:
    """Build the lock-step rig of ``sim_config`` with the controller config ``ctl_config``,
    serve the daemon until SIGTERM/SIGINT or ``shutdown``; returns why it stopped.
    ``placement``: the CPUs of the loop thread and the truth worker (default: the first two)."""
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.config.build_model import build_model
    from cdcr_ctl.control import trajectory
    from cdcr_ctl.control.ports import attach_attitude
    from cdcr_ctl.daemon.service import Daemon, RigIO
    from cdcr_ctl.runlog.writer.factory import RunLogFactory
    from cdcr_ctl.sim.lockstep.rig import LockstepRig
    from cdcr_ctl.sim.simconfig import load_sim_config

    loaded = load_sim_config(sim_config)
    path = Path(ctl_config)
    cfg = load_rig_config(path)  # a bad config stops here: nothing opened, nothing enabled
    if socket_path:
        cfg = cfg.model_copy(
            update={"daemon": cfg.daemon.model_copy(update={"socket_path": socket_path})}
        )
    model = build_model(cfg, source=str(path))
    # The loop runs on simulated time: in lock-step it outpaces the disk, so a full run-log ring
    # makes it wait for the writer (no row may be dropped: the logs are the same on every run).
    sinks = RunLogFactory.from_config(cfg, path, on_full="wait")
    rig = LockstepRig.open(loaded, cfg, str(path), placement=placement)
    assert rig.drives is not None
    io = RigIO(rig.drives, rig.tensions, rig.tip, close=rig.close, attitude=rig.attitude)
    attach_attitude(model, io)

    def settle(req: Any) -> None:
        # A command that starts motion waits until the loop has settled (taken up what came
        # before, nothing left to do), unless a run is going on: it then starts at the same
        # simulated time however the host scheduled the loop thread (SimClock.wait_settled).
        # Past SETTLE_TIMEOUT_S the command acts all the same (the loop may be ramping a jog).
        if req.cmd in SETTLE_BEFORE and d.loop.current_run is None:
            rig.clock.wait_settled(SETTLE_TIMEOUT_S)

    d = Daemon(
        cfg,
        path,
        io,
        model,
        sinks,
        trajectory,
        joystick_opener=rig.open_joystick,
        clock=rig.clock,
        before_command=settle,
    )
    rig.clock.busy = lambda: d.loop.busy
    try:
        d.start()
    except BaseException:
        d.shutdown("start-up failed")
        raise
    click.echo(
        json.dumps(
            {
                "ready": True,
                "clock": "lockstep",
                "socket": cfg.daemon.socket_path,
                "rate_hz": cfg.control.rate_hz,
                "placement": rig.placement.describe(),
            }
        )
    )
    sys.stdout.flush()
    reason = d.serve()
    logging.getLogger(__name__).info(
        "lock-step: %d cycles, %.1f s simulated", rig.clock.cycles, rig.clock.now()
    )
    return reason
