"""The daemon's log commands: ``log-start`` and ``log-stop`` (a manual run log of every cycle),
and the raw CAN traffic log a run directory gets.

:class:`LogCommands` is a mixin of :class:`~cdcr_ctl.daemon.service.Daemon`.
"""

from __future__ import annotations

from typing import Any

from cdcr_ctl.daemon.bustap import TeeListener
from cdcr_ctl.errors import RigError


class LogCommands:
    """Manual log and traffic log commands (mixin of the daemon)."""

    def _cmd_log_start(self, args: Any) -> dict[str, Any]:
        if self._manual_sink is not None:
            raise RigError("a manual log is already running")
        self._manual_sink = self.new_sink(args.name, self.loop.cfg.compensation)
        self._log_traffic(self._manual_sink)
        self.loop.attach_sink(self._manual_sink)
        return {"log_dir": str(getattr(self._manual_sink, "run_dir", ""))}

    def _cmd_log_stop(self, args: Any) -> dict[str, Any]:
        if self._manual_sink is None:
            raise RigError("no manual log is running")
        out = str(getattr(self._manual_sink, "run_dir", ""))
        self._close_manual_sink()
        return {"log_dir": out}

    def _close_manual_sink(self) -> None:
        sink, self._manual_sink = self._manual_sink, None
        if sink is not None:
            self.loop.attach_sink(None)
            sink.close("log stopped", outcome="completed")

    def _log_traffic(self, sink: Any) -> None:
        """Raw CAN traffic into the run directory, from now until the next run or shutdown."""
        start = getattr(self.io.drives, "log_traffic", None)
        path = getattr(sink, "can_log_path", None)
        if start is not None and path is not None and self.cfg.can.log_traffic:
            tap = getattr(sink, "can_tap", None)  # the run's MCAP /can channel
            # ``stop`` is timed on the frames this log records (:mod:`.bustap`).
            bus_tap = self.bus_tap
            start(path("asc"), bus_tap if tap is None else TeeListener(tap, bus_tap))
