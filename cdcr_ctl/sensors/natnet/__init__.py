"""OptiTrack NatNet stream protocol: messages, server info and frame-of-data packets (pure bytes).

Nothing here opens a socket: these functions turn bytes into dataclasses and back, so the
client (:mod:`cdcr_ctl.sensors.tracker`) and the simulated server (``cdcr_ctl.sim.tracker``) share
one definition of the format, and tests check it byte by byte.

Implemented: the binary NatNet stream **versions 3.0, 3.1, 4.0 and 4.1** (Motive 2.x-3.1), as
OptiTrack's NatNet SDK 4.1 sample clients (``PacketClient.cpp``, ``NatNetClient.py``) read it.
A server reporting a later 4.x version is read with the 4.1 layout; 2.x and earlier are rejected.
Everything is little endian; ``i32``/``u32``/``i16``/``u16``/``f32``/``f64``/``u64`` below.

This package re-exports every name of the former ``sensors/natnet.py``. Its rooms:
:mod:`~cdcr_ctl.sensors.natnet.messages` (header, ids, versions, packet dataclasses, connect,
keep-alive, server info) and :mod:`~cdcr_ctl.sensors.natnet.frame` (frame-of-data parse and pack;
the byte layout and the decoder's strictness are described there).
"""

from cdcr_ctl.sensors.natnet.frame import check_version, pack_frame_of_data, parse_frame_of_data
from cdcr_ctl.sensors.natnet.messages import (
    DEFAULT_VERSION,
    HEADER,
    MAX_PAYLOAD_BYTES,
    MIN_VERSION,
    SERVER_NAME_BYTES,
    FrameOfData,
    LabeledMarker,
    MarkerSet,
    MessageId,
    NatNetDecodeError,
    NatNetVersion,
    RigidBodyPose,
    ServerInfo,
    pack_connect,
    pack_keepalive,
    pack_message,
    pack_server_info,
    parse_server_info,
    split_message,
)

__all__ = [
    "DEFAULT_VERSION",
    "HEADER",
    "MAX_PAYLOAD_BYTES",
    "MIN_VERSION",
    "SERVER_NAME_BYTES",
    "FrameOfData",
    "LabeledMarker",
    "MarkerSet",
    "MessageId",
    "NatNetDecodeError",
    "NatNetVersion",
    "RigidBodyPose",
    "ServerInfo",
    "check_version",
    "pack_connect",
    "pack_frame_of_data",
    "pack_keepalive",
    "pack_message",
    "pack_server_info",
    "parse_frame_of_data",
    "parse_server_info",
    "split_message",
]
