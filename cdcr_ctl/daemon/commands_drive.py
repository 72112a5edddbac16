"""The daemon's drive commands: ``enable``, ``disable``, ``home``, ``stop``, ``reset-fault``,
``compensation`` and ``shutdown``.

:class:`DriveCommands` handles them on the daemon's narrow :class:`~cdcr_ctl.daemon.rig.Rig`
view (it never imports the daemon).
"""

from __future__ import annotations

from typing import Any

from cdcr_ctl.control.supervisor import Reaction
from cdcr_ctl.daemon import recovery
from cdcr_ctl.daemon.protocol import ProtocolError
from cdcr_ctl.daemon.rig import Rig
from cdcr_ctl.daemon.rigshare import stop_reaction
from cdcr_ctl.errors import RigError


class DriveCommands:
    """Drive and state commands on ``rig``; :attr:`handlers` maps each command to its method."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.handlers = {
            "enable": self.enable,
            "disable": self.disable,
            "home": self.home,
            "stop": self.stop,
            "compensation": self.compensation,
            "reset_fault": self.reset_fault,
            "shutdown": self.shutdown,
        }

    def enable(self, args: Any) -> dict[str, Any]:
        if self.rig.supervisor.trip is not None:
            raise RigError(
                f"supervisor tripped ({self.rig.supervisor.trip.cause}): reset-fault first"
            )
        self.rig.io.drives.enable()
        self.rig.loop.drives_reenabled()
        self.rig.enabled = True
        self.rig.state = "enabled"
        return {"enabled": True}

    def disable(self, args: Any) -> dict[str, Any]:
        self.rig.loop.request_stop(Reaction.HALT)
        self.rig.io.drives.disable()
        self.rig.enabled = False
        self.rig.state = "ready"
        return {"enabled": False}

    def home(self, args: Any) -> dict[str, Any]:
        if self.rig.loop.current_run is not None:
            raise RigError("a run is in progress: stop it before homing")
        if self.rig.enabled:
            # Homing on the current position (37) declares the arm straight there: bring a bent
            # arm straight first, at the lead-in's cable speed.
            recovery.straighten(self.rig)
        self.rig.loop.pause(True)
        home: list[int] | None = None
        try:
            home = self.rig.io.drives.home()
            # The new home before the loop sends again: no cycle with the old one.
            self.rig.loop.set_home(home)
        finally:
            self.rig.loop.pause(False)
        # Reply once the loop has taken the home up (status shows the new home).
        self.rig._wait_cycles(2)
        self.rig.homed = True
        return {
            "home_counts": list(home),
            "position_counts": [f.position_counts for f in self.rig.io.drives.feedback()],
        }

    def stop(self, args: Any) -> dict[str, Any]:
        """Set the loop's stop flag (no lock, no queue) and answer once the loop has acted:
        the reply names the cycle that sent the stop and how many cycles it took."""
        return stopped(self.rig, args.mode, recovery.stop_now(self.rig, stop_reaction(args.mode)))

    def compensation(self, args: Any) -> dict[str, Any]:
        self.rig.loop.set_compensation(args.mode)
        return {"compensation": args.mode}

    def reset_fault(self, args: Any) -> dict[str, Any]:
        if not args.confirm:
            raise ProtocolError("set confirm: true to reset a fault", field="args.confirm")
        return recovery.reset_fault(self.rig)

    def shutdown(self, args: Any) -> dict[str, Any]:
        self.rig.request_stop("shutdown requested")
        return {"stopping": True}


def stopped(rig: Rig, mode: str, acted: dict[str, Any]) -> dict[str, Any]:
    """The reply to ``stop`` once the loop acted (``acted``: :func:`recovery.await_stop`),
    and ``rig``'s state after it."""
    if stop_reaction(mode) is Reaction.QUICK_STOP:
        rig.enabled = False
        rig.state = "stopped"
    return {"stopped": mode, **acted}
