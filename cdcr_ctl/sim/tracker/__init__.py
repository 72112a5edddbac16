"""Simulated tip trackers on loopback: a NatNet server (Motive stand-in) and a line-stream sender.

Both sample a *truth* callable at their frame rate, add noise, latency and occlusion dropouts,
and serve the result on 127.0.0.1 only (a non-loopback address is refused: the simulator never
sends to a real interface, and never multicasts).

The truth callable takes no argument and returns the pose now, either as ``(R, p_mm)`` (a 3x3
rotation and a position in mm) or as a bare position ``p_mm`` (rotation = identity):

- ``truth_frame="base"``: the TIP pose in the robot base frame (what the robot model computes);
  the simulator inverts the tracker transform (``transform``: the *true* alignment, which may
  differ from the controller's config to simulate a calibration error) to get the rigid body's
  pose in the tracker frame;
- ``truth_frame="tracker"``: the rigid BODY pose in the tracker frame (mm).

Fault hooks: :meth:`pause` (stop serving: no frames, no answers), :meth:`resume`,
:meth:`occlude` (force the body lost), :meth:`inject` (send raw bytes, e.g. garbage), and for
TCP :meth:`SimLineStreamServer.hang_up` (close the connection).

This package re-exports every name of the former ``sim/tracker.py``. Its rooms:
:mod:`~cdcr_ctl.sim.tracker.feed` (truth, true alignment, noise),
:mod:`~cdcr_ctl.sim.tracker.server` (loopback-only serving thread),
:mod:`~cdcr_ctl.sim.tracker.natnet_server` and :mod:`~cdcr_ctl.sim.tracker.stream_server` (the two
devices) and :mod:`~cdcr_ctl.sim.tracker.process` (from config, and the standalone process).
"""

from cdcr_ctl.sim.tracker.feed import Pose, Truth, TruthSampler, true_transform
from cdcr_ctl.sim.tracker.natnet_server import SIM_CLOCK_HZ, SUBSCRIBER_TIMEOUT_S, SimNatNetServer
from cdcr_ctl.sim.tracker.process import main, sim_tracker_from_config
from cdcr_ctl.sim.tracker.server import LOOP_WAIT_S, require_loopback
from cdcr_ctl.sim.tracker.stream_server import SimLineStreamServer

__all__ = [
    "LOOP_WAIT_S",
    "SIM_CLOCK_HZ",
    "SUBSCRIBER_TIMEOUT_S",
    "Pose",
    "SimLineStreamServer",
    "SimNatNetServer",
    "Truth",
    "TruthSampler",
    "main",
    "require_loopback",
    "sim_tracker_from_config",
    "true_transform",
]
