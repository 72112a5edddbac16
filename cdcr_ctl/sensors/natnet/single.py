"""The NAT_FRAMEOFDATA datagram of one rigid body and nothing else, as one ``struct``.

A simulated server (and a Motive stream set to one rigid body) sends the same layout every frame:
the header, one rigid body, every other list empty, the suffix and the end-of-data tag. Packing
and reading it with one precompiled ``struct`` per stream version gives the bytes and the values
of :func:`~cdcr_ctl.sensors.natnet.frame.pack_frame_of_data` and
:func:`~cdcr_ctl.sensors.natnet.frame.parse_frame_of_data` without their per-field calls
(``tests/sensors/test_natnet_single.py`` holds them equal). :func:`read_single_body_frame`
accepts only a datagram the general decoder reads without error and to the same values; anything
else (other layouts, other messages, bad sizes) gives None and goes to the general decoder.
"""

from __future__ import annotations

import math
import struct
from functools import cache
from typing import NamedTuple

from cdcr_ctl.sensors.natnet.frame import _precision_timestamp, _signed16
from cdcr_ctl.sensors.natnet.messages import _RIGID_BODY, MIN_VERSION, MessageId, NatNetVersion

_FRAME_ID = int(MessageId.NAT_FRAMEOFDATA)


class SingleBodyFrame(NamedTuple):
    """The fields of a one-rigid-body frame (units as in
    :class:`~cdcr_ctl.sensors.natnet.FrameOfData` and
    :class:`~cdcr_ctl.sensors.natnet.RigidBodyPose`; ``body_params``: the body's i16 params,
    bit 0 tracking valid; ``params``: the suffix flags, 0..65535)."""

    frame_number: int
    body_id: int
    x: float
    y: float
    z: float
    qx: float
    qy: float
    qz: float
    qw: float
    mean_error: float
    body_params: int
    timecode: int
    timecode_sub: int
    timestamp_s: float
    stamp_mid_exposure: int
    stamp_data_received: int
    stamp_transmit: int
    params: int


class _Layout(NamedTuple):
    st: struct.Struct
    sized: bool
    precision: bool  # NatNet >= 4.0: the precision timestamp in the suffix


@cache
def _layout(sized: bool, precision: bool) -> _Layout:
    """The whole datagram (header, payload, end-of-data tag) of one rigid body."""
    n = "iI" if sized else "i"  # a list's count (and its byte size from NatNet 4.1 on)
    after = 5 if sized else 4  # skeletons, [assets,] labeled markers, force plates, devices
    fmt = (
        "<HH"  # header: message id, payload size
        + "i"  # frame number
        + n * 2  # marker sets, other markers: empty
        + n  # rigid bodies: 1 (and 38 bytes)
        + _RIGID_BODY.format.lstrip("<")
        + n * after  # empty
        + "IIdQQQ"
        + ("iI" if precision else "")
        + "h"  # params
        + "i"  # end-of-data tag
    )
    return _Layout(struct.Struct(fmt), sized, precision)


def _layout_of(version: NatNetVersion) -> _Layout:
    return _layout((version.major, version.minor) >= (4, 1), version.major >= 4)


def pack_single_body_frame(version: NatNetVersion, frame: SingleBodyFrame) -> bytes:
    """The datagram :func:`~cdcr_ctl.sensors.natnet.pack_frame_of_data` makes of a frame with
    this one rigid body and no markers, in stream ``version`` (3.0 or later: the caller checks).
    """
    lay = _layout_of(version)
    st = lay.st
    body = (frame.body_id, *frame[2:11])
    if lay.sized:
        head = (_FRAME_ID, st.size - 4, frame.frame_number, 0, 0, 0, 0, 1, _RIGID_BODY.size)
        lists = (0, 0) * 5
    else:
        head = (_FRAME_ID, st.size - 4, frame.frame_number, 0, 0, 1)
        lists = (0,) * 4
    stamps = frame[11:17]
    precision = _precision_timestamp(frame.timestamp_s) if lay.precision else ()
    return st.pack(
        *head,
        *body[:-1],
        _signed16(body[-1]),
        *lists,
        *stamps,
        *precision,
        _signed16(frame.params),
        0,
    )


def read_single_body_frame(datagram: bytes, version: NatNetVersion) -> SingleBodyFrame | None:
    """The fields of ``datagram`` when it is a NAT_FRAMEOFDATA of stream ``version`` holding one
    rigid body and nothing else (end-of-data tag present or not), with every list size what the
    general decoder accepts and a finite timestamp; None for anything else."""
    if (version.major, version.minor) < (MIN_VERSION.major, MIN_VERSION.minor):
        return None
    lay = _layout_of(version)
    st = lay.st
    size = len(datagram)
    if size == st.size:
        v = st.unpack_from(datagram)
    elif size == st.size - 4:  # without the end-of-data tag
        v = st.unpack(bytes(datagram) + b"\0\0\0\0")
    else:
        return None
    if v[0] != _FRAME_ID or v[1] != size - 4:
        return None
    if lay.sized:
        # counts and sizes: marker sets, other markers, rigid bodies (1 of 38 bytes)
        if v[3:9] != (0, 0, 0, 0, 1, _RIGID_BODY.size):
            return None
        b = 9
        if v[b + 10 : b + 20] != (0,) * 10:  # skeletons, assets, labeled, plates, devices
            return None
        s = b + 20
    else:
        if v[3:6] != (0, 0, 1):
            return None
        b = 6
        if v[b + 10 : b + 14] != (0,) * 4:  # skeletons, labeled, plates, devices
            return None
        s = b + 14
    timestamp = v[s + 2]
    if not math.isfinite(timestamp):
        return None
    params = v[-2]
    return SingleBodyFrame(
        v[2],
        *v[b : b + 9],
        v[b + 9] & 0xFFFF,
        *v[s : s + 6],
        params & 0xFFFF,
    )
