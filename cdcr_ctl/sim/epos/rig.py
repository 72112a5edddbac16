"""The simulated drives of a rig config on their own CAN bus, reachable in-process or over slcan."""

from __future__ import annotations

import collections
import itertools
import logging
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

import can
import canopen

from cdcr_ctl.config.drives import DriveConfig
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.sim.epos.node import DEFAULT_LAG_CYCLES, SimEpos
from cdcr_ctl.sim.epos.plant import MotorParams
from cdcr_ctl.sim.slcan_device import SlcanDevice

log = logging.getLogger(__name__)

_channels = itertools.count(1)

#: How often the drives' heartbeat consumers are checked when no SYNC comes (s).
CONSUMER_CHECK_S = 0.01
#: The nodes' bus listener wakes this often when idle; stopping waits at most this long (s).
NOTIFIER_CYCLE_S = 0.05
#: free_run: with no SYNC for this long, the drives advance on the wall clock (s).
FREE_RUN_AFTER_S = 0.05

NodeSpec = tuple[int, str]  # (node id, "epos4" | "epos2")


class _AdapterBus(can.BusABC):
    """The nodes' side of the simulated slcan adapter: what the nodes send goes straight to the
    adapter (and from there to the host); what the host sends the adapter delivers to the nodes'
    network directly (:meth:`SimDriveBus._deliver`). No queue, no copy, no listener thread."""

    def __init__(self, **kwargs: Any) -> None:
        self.device: SlcanDevice | None = None
        super().__init__(channel="cdcr-sim-adapter", **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        device = self.device
        if device is None:
            raise can.CanOperationError("the simulated adapter is not attached")
        device.on_message_received(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        raise can.CanOperationError("the simulated adapter delivers frames itself")


class SimDriveBus:
    """One :class:`SimEpos` per drive, booted on :meth:`start`.

    ``drives``: a rig config (its drives in cable order, its bit rate), or drive configs, or
    (node id, kind) pairs. ``interface="virtual"``: the nodes sit on python-can virtual channel
    ``channel`` (the controller opens the same channel in this process). ``interface="slcan"``:
    the nodes sit on a private virtual channel bridged to an slcan pseudo-terminal
    (:attr:`channel_path`; ``link`` symlinks to it; ``tcp``: on a loopback TCP port instead,
    ``tcp_port`` or one the kernel picks, :attr:`channel_path` ``socket://127.0.0.1:PORT``).
    ``motors`` overrides the motor parameters per node id. ``free_run``: advance the drives on
    the wall clock while no SYNC comes (a master that never sends SYNC still sees profile moves
    finish); off by default, so that time moves only with SYNC and runs are reproducible.
    ``lag_cycles``: feedback lag of every node in SYNCs (:attr:`SimEpos.lag_cycles`; 1 as on a
    real drive). ``sync_period_s``: the time between two SYNCs (a rig config gives its
    ``can.sync_period_s``; None: each node's 0x60C2).
    """

    def __init__(
        self,
        drives: RigConfig | Sequence[DriveConfig] | Sequence[NodeSpec],
        interface: str = "virtual",
        channel: str = "cdcr",
        link: str | None = None,
        *,
        bitrate: int | None = None,
        motors: Mapping[int, MotorParams] | None = None,
        free_run: bool = False,
        tcp: bool = False,
        tcp_port: int = 0,
        lag_cycles: int = DEFAULT_LAG_CYCLES,
        sync_period_s: float | None = None,
    ) -> None:
        specs, rate = _specs(drives)
        if sync_period_s is None and isinstance(drives, RigConfig):
            sync_period_s = drives.can.sync_period_s

        self.bitrate = bitrate or rate
        self.interface = interface
        self.device: SlcanDevice | None = None
        self._bus: can.BusABC
        if interface == "slcan":
            # The adapter hands the host's frames to the nodes in its reader thread and their
            # answers back in the same write: as few thread switches as a 1 kHz SYNC allows.
            adapter = _AdapterBus()
            self._bus = adapter
            self.device = SlcanDevice(
                None, link, bitrate=self.bitrate, deliver=self._deliver, tcp=tcp, tcp_port=tcp_port
            )
            adapter.device = self.device
            self.channel_path = self.device.path
        elif interface == "virtual":
            self._bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
            self.channel_path = channel
        else:
            raise ValueError(f"the simulated drives serve 'virtual' or 'slcan', not {interface!r}")
        self.network = canopen.Network(self._bus)
        self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        if interface == "virtual":
            self.network.connect()
        motors = motors or {}
        self.nodes = [
            SimEpos(self.network, nid, kind, motors.get(nid, MotorParams(counts_per_rev=cpr)))
            for nid, kind, cpr in specs
        ]
        for n in self.nodes:
            n.lag_cycles = lag_cycles
            n.sync_period_s = sync_period_s
        self.free_run = free_run
        #: Frames the host (the controller) sent through the adapter, by :func:`frame_kind`.
        self.host_frames: collections.Counter[str] = collections.Counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._background, name="sim-epos", daemon=True)

    def _deliver(self, msg: can.Message) -> None:
        """A frame from the host to every node (the adapter's reader thread), as canopen's
        MessageListener would pass it on."""
        if msg.is_error_frame or msg.is_remote_frame:
            return
        self.host_frames[frame_kind(msg.arbitration_id)] += 1
        try:
            self.network.notify(msg.arbitration_id, msg.data, msg.timestamp)
        except Exception:  # a node's bug must not stop the adapter
            log.exception("simulated drives: handling 0x%03X failed", msg.arbitration_id)

    def start(self) -> SimDriveBus:
        for n in self.nodes:
            n.boot()
        self._thread.start()
        return self

    def _background(self) -> None:
        last_sync = [n.sync_count for n in self.nodes]
        last_change = time.monotonic()
        last_step = last_change
        while not self._stop.wait(CONSUMER_CHECK_S):
            now = time.monotonic()
            for n in self.nodes:
                n.check_master_heartbeat(now)
            if not self.free_run:
                continue
            syncs = [n.sync_count for n in self.nodes]
            if syncs != last_sync:
                last_sync, last_change, last_step = syncs, now, now
            elif now - last_change > FREE_RUN_AFTER_S:
                for n in self.nodes:
                    if not n.silent:
                        n.step(now - last_step)
                last_step = now

    def node(self, node_id: int) -> SimEpos:
        """The simulated drive with ``node_id`` (KeyError if none)."""
        for n in self.nodes:
            if n.node_id == node_id:
                return n
        raise KeyError(f"no simulated drive with node id {node_id}")

    def actual_positions(self) -> list[int]:
        """Actual positions (counts) in drive order (cable order for a rig config)."""
        return [n.position_counts for n in self.nodes]

    def stats(self) -> list[dict[str, object]]:
        """Per drive: node id, SYNCs seen, set-points missed, largest CSP following error
        (counts), and the intervals between SYNC arrivals (s: p50, p99, p99.9, max)."""
        out: list[dict[str, object]] = []
        for n in self.nodes:
            times = list(n.sync_times_s)
            gaps = sorted(b - a for a, b in itertools.pairwise(times))

            def pct(q: float, gaps: list[float] = gaps) -> float | None:
                return gaps[min(len(gaps) - 1, int(q * len(gaps)))] if gaps else None

            out.append(
                {
                    "node": n.node_id,
                    "syncs": n.sync_count,
                    "missed_setpoints": n.missed_setpoints,
                    "max_following_error_counts": round(n.max_following_error_counts, 3),
                    "sync_interval_s": {
                        "p50": pct(0.5),
                        "p99": pct(0.99),
                        "p99.9": pct(0.999),
                        "max": gaps[-1] if gaps else None,
                    },
                }
            )
        return out

    def reset_stats(self) -> None:
        for n in self.nodes:
            n.sync_times_s.clear()
            n.missed_setpoints = 0
            n.max_following_error_counts = 0.0
            n.sync_count = 0

    def step(self, dt_s: float) -> None:
        """Advance every drive by ``dt_s`` seconds (use with ``advance_on_sync = False``)."""
        for n in self.nodes:
            n.step(dt_s)

    def unplug(self) -> None:
        """Fault hook: the bus disappears for the controller (slcan: the adapter's pty closes;
        virtual: every drive goes silent)."""
        if self.device is not None:
            self.device.unplug()
        else:
            for n in self.nodes:
                n.go_silent()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(1.0)
        for n in self.nodes:
            n.node.nmt.stop_heartbeat()
        if self.device is not None:
            self.device.stop()
        self.network.disconnect()

    def __enter__(self) -> SimDriveBus:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def frame_kind(cob_id: int) -> str:
    """The CiA 301 service of a host frame by its COB-ID: ``nmt``, ``sync``, ``time``,
    ``rpdo``, ``sdo_request``, ``heartbeat`` (a master's own), else ``other``."""
    if cob_id == 0x000:
        return "nmt"
    if cob_id == 0x080:
        return "sync"
    if cob_id == 0x100:
        return "time"
    if 0x200 <= cob_id <= 0x57F:
        return "rpdo"
    if 0x600 <= cob_id <= 0x67F:
        return "sdo_request"
    if 0x700 <= cob_id <= 0x77F:
        return "heartbeat"
    return "other"


def _specs(
    drives: RigConfig | Sequence[DriveConfig] | Sequence[NodeSpec],
) -> tuple[list[tuple[int, str, int]], int]:
    """(node id, kind, encoder counts per rev) per drive, and the bus bit rate."""
    if isinstance(drives, RigConfig):
        by_cable = {d.cable: d for d in drives.drives}
        ordered = [by_cable[c.name] for c in drives.robot.cables if c.name in by_cable]
        ordered += [d for d in drives.drives if d not in ordered]
        return [(d.node_id, d.type, d.encoder_counts_per_rev) for d in ordered], drives.can.bitrate
    out = []
    for d in drives:
        if isinstance(d, DriveConfig):
            out.append((d.node_id, d.type, d.encoder_counts_per_rev))
        else:
            nid, kind = d
            out.append((int(nid), str(kind), MotorParams().counts_per_rev))
    return out, 1_000_000
