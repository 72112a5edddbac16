"""Tip tracker: OptiTrack NatNet rigid body or a plain line stream, as the tip in the base frame.

Two readers, one output. :class:`NatNetTracker` is a NatNet client (protocol in
:mod:`cdcr_ctl.sensors.natnet`) for one rigid body; :class:`LineStreamTracker` reads the plain
line stream below over UDP or TCP (laser trackers, bridges). Both turn every good measurement
into the tip position in the ROBOT BASE FRAME (mm) with :class:`TrackerTransform` and publish it
with its acquisition time; the control loop calls ``latest()`` and never waits on the network.

Frames and units. The tracker reports the rigid body's pose in its own frame and units:
position ``p_b`` (units) and rotation ``R_tb`` (body -> tracker). With ``s`` = mm per unit,
``(R_mb, t_mb)`` = ``marker_to_tip`` (tip frame -> body frame, mm) and ``(R_bt, t_bt)`` =
``base_from_tracker`` (tracker frame -> base frame, mm)::

    p_tip_tracker_mm = s * p_b + R_tb @ t_mb
    p_tip_base_mm    = R_bt @ p_tip_tracker_mm + t_bt
    R_base_tip       = R_bt @ R_tb @ R_mb

Line stream format (ASCII, one measurement per line, ``\\n`` or ``\\r\\n`` terminated)::

    t_s,x,y,z[,qx,qy,qz,qw]

``t_s``: the sender's timestamp (s, any epoch, increasing). ``x,y,z``: the measured point in the
tracker frame, in tracker units (mm unless ``units_to_mm`` says otherwise). ``qx,qy,qz,qw``:
optional unit quaternion (scalar last) of the target's orientation (6-DoF trackers); without it
the orientation is taken as the identity, so ``marker_to_tip.translation_mm`` is then an offset
along the tracker's axes. Numbers are decimals (``-12.5``, ``1e-3``); spaces around fields are
allowed; lines starting with ``#`` and empty lines are ignored; anything else that is not such a
line (wrong field count, non-finite numbers, a quaternion of norm far from 1, over
:data:`MAX_LINE_BYTES`) is counted as bad and skipped. Over UDP a datagram carries whole lines
(its end also ends a line); over TCP lines may be split anywhere.

This package re-exports every name of the former ``sensors/tracker.py``; its rooms:
``frames`` (rotations, :class:`TrackerTransform`), ``linestream`` (parse/format one line, pure),
``reader`` (samples, :class:`TipTracker`), ``natnet_client`` (:class:`NatNetTracker`),
``stream_client`` (:class:`LineStreamTracker`) and ``opener`` (:func:`open_tracker` from config).
"""

from cdcr_ctl.sensors.tracker.frames import (
    QUATERNION_NORM_TOL,
    TrackerTransform,
    quaternion_from_rotation,
    rotation_from_quaternion,
    rotation_from_rotvec,
)
from cdcr_ctl.sensors.tracker.linestream import (
    MAX_LINE_BYTES,
    StreamPoint,
    format_stream_line,
    parse_stream_line,
)
from cdcr_ctl.sensors.tracker.natnet_client import (
    KEEPALIVE_PERIOD_S,
    RECONNECT_PERIOD_S,
    NatNetTracker,
)
from cdcr_ctl.sensors.tracker.opener import local_bind_address, open_tracker
from cdcr_ctl.sensors.tracker.reader import (
    MAX_DATAGRAMS_PER_POLL,
    RECV_BUFFER_BYTES,
    RECV_POLL_S,
    REORDER_WINDOW_FRAMES,
    REORDER_WINDOW_S,
    TipMeasurement,
    TipSample,
    TipTracker,
    TrackerStats,
)
from cdcr_ctl.sensors.tracker.stream_client import LineStreamTracker

__all__ = [
    "KEEPALIVE_PERIOD_S",
    "MAX_DATAGRAMS_PER_POLL",
    "MAX_LINE_BYTES",
    "QUATERNION_NORM_TOL",
    "RECONNECT_PERIOD_S",
    "RECV_BUFFER_BYTES",
    "RECV_POLL_S",
    "REORDER_WINDOW_FRAMES",
    "REORDER_WINDOW_S",
    "LineStreamTracker",
    "NatNetTracker",
    "StreamPoint",
    "TipMeasurement",
    "TipSample",
    "TipTracker",
    "TrackerStats",
    "TrackerTransform",
    "format_stream_line",
    "local_bind_address",
    "open_tracker",
    "parse_stream_line",
    "quaternion_from_rotation",
    "rotation_from_quaternion",
    "rotation_from_rotvec",
]
