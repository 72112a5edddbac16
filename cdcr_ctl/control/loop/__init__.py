"""The real-time loop: setpoint -> inverse kinematics -> compensation -> limits -> RPDOs + SYNC.

One thread, fixed rate on absolute monotonic deadlines (:class:`~cdcr_ctl.control.timing.Ticker`).
Per cycle:

1. read the latest drive feedback, load-cell tensions and tracker tip (non-blocking);
2. sample the setpoint source (trajectory, jog move or hold) at the cycle time;
3. ideal inverse kinematics ``q_nominal`` and the compensated command ``q_cmd`` (Qi et al. 2023
   eq. 37, mode off/model/measured);
4. the safety supervisor checks commands and measurements; a trip applies its reaction;
5. targets in counts (``home + q_cmd * counts_per_mm``) go out as RPDOs followed by SYNC;
6. one row goes to the run log (queued; the loop keeps the cycle's numbers in one array, the
   writer thread makes the columns and does the disk I/O: :class:`CycleRow`).

Commands from the daemon's socket threads are posted under a lock and picked up at the start of a
cycle (the lock is looked at only when something was posted); nothing on the loop's path blocks
on them. :class:`LoopCounters` times each stage of the cycle (:data:`STAGES`) and its CPU time.

Modules: :mod:`.cycle` (the loop thread and the cycle), :mod:`.commands` (commands and their
queue), :mod:`.records` (config, runs, counters, constants), :mod:`.rows` (the log row).
"""

from dataclasses import field

from cdcr_ctl.control.loop.commands import LoopCommands
from cdcr_ctl.control.loop.cycle import ControlLoop, log
from cdcr_ctl.control.loop.records import (
    COMMAND_STEP_FRACTION,
    DIVERGENCE_LAG_S,
    GIL_SWITCH_INTERVAL_S,
    OFFSET_RAMP_FRACTION,
    OPERATOR_STOP,
    STAGES,
    Hold,
    LoopConfig,
    LoopCounters,
    RunInfo,
    TipHistory,
    _Command,
)
from cdcr_ctl.control.loop.rows import CycleRow, RowLayout, RowSink
from cdcr_ctl.control.stopflag import StopFlag

__all__ = [
    "COMMAND_STEP_FRACTION",
    "DIVERGENCE_LAG_S",
    "GIL_SWITCH_INTERVAL_S",
    "OFFSET_RAMP_FRACTION",
    "OPERATOR_STOP",
    "STAGES",
    "ControlLoop",
    "CycleRow",
    "Hold",
    "LoopCommands",
    "LoopConfig",
    "LoopCounters",
    "RowLayout",
    "RowSink",
    "RunInfo",
    "StopFlag",
    "TipHistory",
    "_Command",
    "field",
    "log",
]
