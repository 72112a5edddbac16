"""The daemon's drive commands: ``enable``, ``disable``, ``home``, ``stop``, ``reset-fault``,
``compensation`` and ``shutdown``.

:class:`DriveCommands` is a mixin of :class:`~cdcr_ctl.daemon.service.Daemon`.
"""

from __future__ import annotations

from typing import Any

from cdcr_ctl.control.supervisor import Reaction
from cdcr_ctl.daemon import recovery
from cdcr_ctl.daemon.protocol import ProtocolError
from cdcr_ctl.daemon.rigshare import stop_reaction
from cdcr_ctl.errors import RigError


class DriveCommands:
    """Drive and state commands (mixin of the daemon)."""

    def _cmd_enable(self, args: Any) -> dict[str, Any]:
        if self.supervisor.trip is not None:
            raise RigError(f"supervisor tripped ({self.supervisor.trip.cause}): reset-fault first")
        self.io.drives.enable()
        self.loop.drives_reenabled()
        self.enabled = True
        self.state = "enabled"
        return {"enabled": True}

    def _cmd_disable(self, args: Any) -> dict[str, Any]:
        self.loop.request_stop(Reaction.HALT)
        self.io.drives.disable()
        self.enabled = False
        self.state = "ready"
        return {"enabled": False}

    def _cmd_home(self, args: Any) -> dict[str, Any]:
        if self.loop.current_run is not None:
            raise RigError("a run is in progress: stop it before homing")
        if self.enabled:
            # Homing on the current position (37) declares the arm straight there: bring a bent
            # arm straight first, at the lead-in's cable speed.
            recovery.straighten(self)
        self.loop.pause(True)
        home: list[int] | None = None
        try:
            home = self.io.drives.home()
            # The new home before the loop sends again: no cycle with the old one.
            self.loop.set_home(home)
        finally:
            self.loop.pause(False)
        # Reply once the loop has taken the home up (status shows the new home).
        self._wait_cycles(2)
        self.homed = True
        return {
            "home_counts": list(home),
            "position_counts": [f.position_counts for f in self.io.drives.feedback()],
        }

    def _cmd_stop(self, args: Any) -> dict[str, Any]:
        """Set the loop's stop flag (no lock, no queue) and answer once the loop has acted:
        the reply names the cycle that sent the stop and how many cycles it took."""
        return self.stopped(args.mode, recovery.stop_now(self, stop_reaction(args.mode)))

    def stopped(self, mode: str, acted: dict[str, Any]) -> dict[str, Any]:
        """The reply to ``stop`` once the loop acted (``acted``: :func:`recovery.await_stop`),
        and the daemon's state after it."""
        if stop_reaction(mode) is Reaction.QUICK_STOP:
            self.enabled = False
            self.state = "stopped"
        return {"stopped": mode, **acted}

    def _cmd_compensation(self, args: Any) -> dict[str, Any]:
        self.loop.set_compensation(args.mode)
        return {"compensation": args.mode}

    def _cmd_reset_fault(self, args: Any) -> dict[str, Any]:
        if not args.confirm:
            raise ProtocolError("set confirm: true to reset a fault", field="args.confirm")
        return recovery.reset_fault(self)

    def _cmd_shutdown(self, args: Any) -> dict[str, Any]:
        self.request_stop("shutdown requested")
        return {"stopping": True}
