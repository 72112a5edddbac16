"""Line-stream records of the plain tracker stream: parse and format one line (pure bytes).

Format (ASCII, one measurement per line, ``\\n`` or ``\\r\\n`` terminated)::

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
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.sensors.tracker.frames import QUATERNION_NORM_TOL

#: Longest line of the line stream (bytes, without the line end).
MAX_LINE_BYTES = 200


_NUMBER = rb"\s*([+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)\s*"
_LINE = re.compile(_NUMBER + (rb"," + _NUMBER) * 3 + rb"(?:" + (rb"," + _NUMBER) * 4 + rb")?")


@dataclass(frozen=True, slots=True)
class StreamPoint:
    """One line of the line stream: sender time (s), position (tracker units), orientation."""

    t_s: float
    position: tuple[float, float, float]
    orientation_xyzw: tuple[float, float, float, float] | None = None


def parse_stream_line(line: bytes) -> StreamPoint | None:
    """A line (without its line end) as a :class:`StreamPoint`, or None if it is not valid.

    Comments and empty lines are not valid points either: callers skip them before.
    """
    if len(line) > MAX_LINE_BYTES:
        return None
    m = _LINE.fullmatch(line)
    if m is None:
        return None
    values = [float(g) for g in m.groups() if g is not None]
    if not all(math.isfinite(v) for v in values):
        return None
    t, x, y, z = values[:4]
    if len(values) == 4:
        return StreamPoint(t, (x, y, z))
    q = values[4:]
    if abs(math.sqrt(sum(c * c for c in q)) - 1.0) > QUATERNION_NORM_TOL:
        return None
    return StreamPoint(t, (x, y, z), (q[0], q[1], q[2], q[3]))


def format_stream_line(
    t_s: float,
    position: tuple[float, ...] | np.ndarray,
    orientation_xyzw: tuple[float, ...] | np.ndarray | None = None,
) -> bytes:
    """The line for one measurement, ``\\n`` included (positions with 4 decimals)."""
    fields = [f"{t_s:.6f}"] + [f"{float(v):.4f}" for v in position]
    if orientation_xyzw is not None:
        fields += [f"{float(v):.7f}" for v in orientation_xyzw]
    return (",".join(fields) + "\n").encode("ascii")
