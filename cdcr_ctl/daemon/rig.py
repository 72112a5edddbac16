"""The narrow view of the daemon that its command handlers and recovery steps work on.

:class:`Rig` names what a handler (:mod:`.commands_drive`, :mod:`.status`) or a recovery step
(:mod:`.recovery`) may read and set: the validated config, the rig's I/O, the design's model, the
control loop and its supervisor, and the daemon's state flags. The daemon
(:class:`~cdcr_ctl.daemon.service.Daemon`) satisfies it; the handlers never import the daemon.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.control.loop import ControlLoop
from cdcr_ctl.control.ports import RigIO
from cdcr_ctl.control.supervisor import Supervisor
from cdcr_ctl.model.port import RobotModelPort


class Rig(Protocol):
    """What the daemon's handlers see of it (attributes as :class:`~.service.Daemon` sets them)."""

    cfg: RigConfig
    config_path: Path
    io: RigIO
    model: RobotModelPort
    loop: ControlLoop
    supervisor: Supervisor
    #: ``ready``, ``enabled``, ``stopped``, ``fault``, ... as ``status`` shows it.
    state: str
    enabled: bool
    homed: bool
    #: Times ``stop`` on the CAN traffic (:class:`~cdcr_ctl.daemon.bustap.StopBusTap`).
    bus_tap: Any
    #: The manual log's sink (``log_start``) or None; the joystick session or None.
    _manual_sink: Any
    _session: Any

    def _wait_cycles(self, n: int) -> None:
        """Return once the loop has run ``n`` more cycles (bounded)."""

    def request_stop(self, reason: str) -> None:
        """End :meth:`~.service.Daemon.serve` (the daemon shuts down)."""
