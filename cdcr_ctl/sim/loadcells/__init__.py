"""Simulated load-cell transmitters on a pseudo-terminal: a Modbus RTU slave bus or an ASCII stream.

A callable returns the truth tensions (N) per cell; :class:`SensorNoise` adds Gaussian noise, a
linear drift and random dropouts (no reply / a missing line). Fault hooks let tests and the
simulated rig break the link on purpose: :meth:`PtySim.drop_next`, :meth:`PtySim.corrupt_next`
(bad CRC / unparsable line), :meth:`PtySim.inject_garbage`, :meth:`PtySim.split_next` (a frame
written in two pieces), :meth:`PtySim.garble_for` (nothing valid for a while),
:meth:`PtySim.disconnect` (the pty is closed, as if unplugged) / :meth:`PtySim.reconnect`, and
:meth:`TensionFeed.spike` (``sim.feed.spike``: a snagged cable reads high).

Timing: a pty moves bytes instantly and ignores the baud rate. With ``emulate_baud`` the Modbus
slave answers when a real bus would have delivered its last reply byte (request + t3.5 + reply
characters after the request arrived, plus ``turnaround_s``) and the ASCII streamer sends no
faster than its lines take on the wire. The slave's end-of-request silence is ``silence_s``
(default the spec's t3.5: 3.5 characters, fixed 1.75 ms above 19200 bit/s).

Runs in a thread (``with ModbusLoadCellSim(...) as sim: sim.path``) or as its own process::

    python -m cdcr_ctl.sim.loadcells --slaves 1 2 3 --tension-N 5 --link /tmp/cdcr-sim/loadcells
    python -m cdcr_ctl.sim.loadcells --rig config/qi2023-sim.yaml --tension-N 4 5 6

which prints the pty path on its first line of output and serves until SIGINT/SIGTERM.
Framing, CRC and PDUs are pymodbus's; production code never imports this module.

This package re-exports every name of the former ``sim/loadcells.py``. Its rooms:
:mod:`~cdcr_ctl.sim.loadcells.feed` (the world feed: truth, noise, drift, dropouts),
:mod:`~cdcr_ctl.sim.loadcells.pty` (pseudo-terminal, serving thread, fault hooks),
:mod:`~cdcr_ctl.sim.loadcells.modbus` and :mod:`~cdcr_ctl.sim.loadcells.ascii` (the two devices'
protocols) and :mod:`~cdcr_ctl.sim.loadcells.process` (from config, and the standalone process).
"""

from cdcr_ctl.sim.loadcells.ascii import AsciiLoadCellSim
from cdcr_ctl.sim.loadcells.feed import (
    CAPACITY_N,
    OVERLOAD_FRACTION,
    SensorNoise,
    SimStats,
    TensionFeed,
    Tensions,
)
from cdcr_ctl.sim.loadcells.modbus import FRAME_GAP_S, POLL_S, SPARE_REGISTERS, ModbusLoadCellSim
from cdcr_ctl.sim.loadcells.process import _parser as _parser
from cdcr_ctl.sim.loadcells.process import build_sim, main, sim_for_config
from cdcr_ctl.sim.loadcells.pty import GARBLE_NOISE, PtyEndpoint, PtySim

__all__ = [
    "CAPACITY_N",
    "FRAME_GAP_S",
    "GARBLE_NOISE",
    "OVERLOAD_FRACTION",
    "POLL_S",
    "SPARE_REGISTERS",
    "AsciiLoadCellSim",
    "ModbusLoadCellSim",
    "PtyEndpoint",
    "PtySim",
    "SensorNoise",
    "SimStats",
    "TensionFeed",
    "Tensions",
    "build_sim",
    "main",
    "sim_for_config",
]
