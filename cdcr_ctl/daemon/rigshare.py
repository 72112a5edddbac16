"""What the daemon's front process (:mod:`~cdcr_ctl.daemon.front`) and its rig process
(:mod:`~cdcr_ctl.daemon.rigproc`) agree on: the slots of the integer array they share, the
loop's reaction to a ``stop`` of each mode and how long a ``stop`` waits for the loop to act.

A module of its own so that the front, which serves the control socket, imports none of the rig
side (the loop, the drives and their CAN stack, the sensors, the run-log writer, the planner's
scipy.optimize): the rig process imports that, the front process need not.
"""

from __future__ import annotations

from cdcr_ctl.control.stopflag import StopFlag
from cdcr_ctl.control.supervisor import Reaction

#: Slots of the shared integer array between the processes: the StopFlag's, then the rig's
#: heartbeat (counts up while the loop runs: the front pets systemd's watchdog on it).
HEARTBEAT = StopFlag.SLOTS
SHARED_SLOTS = StopFlag.SLOTS + 1

#: Longest wait of ``stop`` for the loop to act (s); a loop that is not running is bypassed.
STOP_ACK_TIMEOUT_S = 1.0


def stop_reaction(mode: str) -> Reaction:
    """The loop's reaction to a ``stop`` of ``mode`` (``quick_stop`` or ``halt``)."""
    return Reaction.QUICK_STOP if mode == "quick_stop" else Reaction.HALT


__all__ = ["HEARTBEAT", "SHARED_SLOTS", "STOP_ACK_TIMEOUT_S", "stop_reaction"]
