"""Which CANopen nodes are on a bus, and do they match the rig config? The bring-up tool.

:func:`scan_bus` asks every node id 1-127 at once for its device type (an SDO upload of 0x1000:00;
a node that exists answers, with the value or an abort) and collects the answers for
``timeout_s``; each node that answered is then asked for its identity 0x1018:01-04 (vendor,
product code, revision, serial) and its manufacturer device name 0x1008 (canopen's SDO client;
segmented upload). Nothing is written: no NMT command, no SDO download; drives keep their state.
The bus must not be in use by a running daemon (one master at a time).

:func:`compare` sets the answers against the config's drives: a configured node that did not
answer (missing), a node whose vendor is not maxon or whose device name is not the configured
family (wrong product), a node the config does not name (extra) and, when a missing drive's
family answers at an unexpected node id, that the id is probably wrong.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from cdcr_ctl.config.drives import DriveConfig
from cdcr_ctl.drives import epos

#: How long the answers to the broadcast of device-type requests are collected (s).
SCAN_TIMEOUT_S = 0.3
#: SDO timeout for the identity reads of nodes that answered (s).
IDENTITY_TIMEOUT_S = 0.3
#: SDO client command: initiate upload request (CiA 301).
_UPLOAD_REQUEST = 0x40


@dataclass(frozen=True)
class ScannedNode:
    """One node that answered: its device type 0x1000 and identity 0x1018 (None: not read)."""

    node_id: int
    device_type: int | None
    vendor_id: int | None = None
    product_code: int | None = None
    revision: int | None = None
    serial: int | None = None
    name: str = ""

    @property
    def family(self) -> str | None:
        """``epos4`` / ``epos2`` from the device name (0x1008), else None."""
        low = self.name.lower().replace(" ", "")
        for fam in ("epos4", "epos2"):
            if fam in low:
                return fam
        return None

    def as_dict(self) -> dict[str, object]:
        d = asdict(self)
        for key in ("device_type", "vendor_id", "product_code", "revision", "serial"):
            if d[key] is not None:
                d[key] = f"0x{d[key]:08X}"
        d["family"] = self.family
        return d


def upload_request(node_id: int, index: int, sub: int) -> tuple[int, bytes]:
    """(COB-ID, data) of an SDO initiate-upload request of ``index:sub`` to ``node_id``."""
    return 0x600 + node_id, struct.pack("<BHB4x", _UPLOAD_REQUEST, index, sub)


def parse_upload_answer(data: bytes, index: int, sub: int) -> tuple[bool, int | None] | None:
    """An SDO server's answer to an upload of ``index:sub``: (answered, expedited value or None
    for an abort / a segmented transfer); None when the frame is not that answer."""
    if len(data) != 8:
        return None
    cmd = data[0]
    a_index, a_sub = struct.unpack_from("<HB", data, 1)
    if (a_index, a_sub) != (index, sub):
        return None
    if cmd == 0x80:  # abort: the node exists but lacks the object
        return True, None
    if cmd & 0xE0 != 0x40:
        return None
    if cmd & 0x02:  # expedited
        n = 4 - ((cmd >> 2) & 0x3) if cmd & 0x01 else 4
        return True, int.from_bytes(data[4 : 4 + n], "little")
    return True, None


def discover(
    bus: can.BusABC, node_ids: Iterable[int] = range(1, 128), timeout_s: float = SCAN_TIMEOUT_S
) -> dict[int, int | None]:
    """Node id -> device type 0x1000 (None: answered without a value) of every node that
    answered an upload of 0x1000:00 within ``timeout_s``."""
    ids = list(node_ids)
    for nid in ids:
        cob, data = upload_request(nid, epos.DEVICE_TYPE, 0)
        bus.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))
    wanted = {0x580 + nid: nid for nid in ids}
    found: dict[int, int | None] = {}
    end = time.monotonic() + timeout_s
    while (left := end - time.monotonic()) > 0:
        msg = bus.recv(left)
        if msg is None or msg.is_error_frame or msg.arbitration_id not in wanted:
            continue
        answer = parse_upload_answer(bytes(msg.data), epos.DEVICE_TYPE, 0)
        if answer is not None:
            found[wanted[msg.arbitration_id]] = answer[1]
    return found


def scan_bus(
    bus: can.BusABC,
    node_ids: Iterable[int] = range(1, 128),
    timeout_s: float = SCAN_TIMEOUT_S,
) -> list[ScannedNode]:
    """Every node on ``bus`` with device type, identity and name, by node id. The bus is used
    and left open (the caller owns it)."""
    found = discover(bus, node_ids, timeout_s)
    net = canopen.Network(bus)
    net.connect()
    out = []
    try:
        for nid in sorted(found):
            node = canopen.RemoteNode(nid, canopen.ObjectDictionary())
            node.sdo.RESPONSE_TIMEOUT = IDENTITY_TIMEOUT_S
            net.add_node(node)
            ident: list[int | None] = []
            for sub in (1, 2, 3, 4):
                try:
                    raw = node.sdo.upload(epos.IDENTITY, sub)
                    ident.append(int.from_bytes(raw[:4].ljust(4, b"\0"), "little"))
                except (SdoAbortedError, SdoCommunicationError):
                    ident.append(None)
            try:
                name = node.sdo.upload(0x1008, 0).decode("ascii", "replace").strip("\0 ")
            except (SdoAbortedError, SdoCommunicationError):
                name = ""
            out.append(ScannedNode(nid, found[nid], *ident, name=name))
    finally:
        # Leave the bus to the caller: stop canopen's listener without shutting the bus down.
        if net.notifier is not None:
            net.notifier.stop(0.1)
    return out


def compare(scanned: Sequence[ScannedNode], drives: Sequence[DriveConfig]) -> list[str]:
    """What differs between the bus and the config, one line each (empty: they match)."""
    by_id = {n.node_id: n for n in scanned}
    configured = {d.node_id for d in drives}
    issues: list[str] = []
    missing = [d for d in drives if d.node_id not in by_id]
    extra = [n for n in scanned if n.node_id not in configured]
    for d in missing:
        line = f"missing: drive {d.name} ({d.type}, node {d.node_id}) did not answer"
        guess = [n for n in extra if n.family == d.type]
        if guess:
            ids = ", ".join(str(n.node_id) for n in guess)
            line += f"; an {d.type.upper()} answers at node {ids}: wrong node id?"
        issues.append(line)
    for d in drives:
        n = by_id.get(d.node_id)
        if n is None:
            continue
        if n.vendor_id is not None and n.vendor_id != epos.MAXON_VENDOR_ID:
            issues.append(
                f"wrong product: node {n.node_id} (drive {d.name}) vendor 0x{n.vendor_id:08X} "
                "is not maxon (0x000000FB)"
            )
        elif n.family is not None and n.family != d.type:
            issues.append(
                f"wrong product: node {n.node_id} is {n.name!r}, the config says drive "
                f"{d.name} is an {d.type.upper()}"
            )
        elif n.device_type is not None and n.device_type & 0xFFFF != 0x0192:
            issues.append(
                f"wrong product: node {n.node_id} device type 0x{n.device_type:08X} is not a "
                "CiA 402 drive"
            )
    for n in extra:
        issues.append(f"extra: node {n.node_id} ({n.name or 'unnamed'}) is not in the config")
    return issues
