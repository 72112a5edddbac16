"""The simulated drives of a rig config on their own CAN bus, reachable in-process or over slcan."""

from __future__ import annotations

import itertools
import threading

import can
import canopen

from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.sim.epos.node import SimEpos
from cdcr_ctl.sim.slcan_device import SlcanDevice

_channels = itertools.count(1)

#: How often the drives' heartbeat consumers are checked when no SYNC comes (s).
CONSUMER_CHECK_S = 0.01


class SimDriveBus:
    """One :class:`SimEpos` per drive of ``rig`` (cable order), booted on start.

    ``interface="virtual"``: the nodes sit on python-can virtual channel ``channel`` (the
    controller opens the same channel in this process). ``interface="slcan"``: the nodes sit on a
    private virtual channel bridged to an slcan pseudo-terminal (``link`` symlinks to it).
    """

    def __init__(
        self,
        rig: RigConfig,
        interface: str = "virtual",
        channel: str = "cdcr",
        link: str | None = None,
    ) -> None:
        self.rig = rig
        self.interface = interface
        if interface == "slcan":
            inner = f"cdcr-sim-{next(_channels)}-{id(self)}"
            self._bus = can.Bus(interface="virtual", channel=inner, receive_own_messages=False)
            self._dev_bus = can.Bus(interface="virtual", channel=inner, receive_own_messages=False)
            self.device: SlcanDevice | None = SlcanDevice(self._dev_bus, link)
            self.channel_path = self.device.path
        elif interface == "virtual":
            self._bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
            self.device = None
            self.channel_path = channel
        else:
            raise ValueError(f"the simulated drives serve 'virtual' or 'slcan', not {interface!r}")
        self.network = canopen.Network(self._bus)
        self.network.connect()
        by_cable = {d.cable: d for d in rig.drives}
        self.drives = [by_cable[c.name] for c in rig.robot.cables]
        self.nodes = [
            SimEpos(self.network, d.node_id, d.type, d.encoder_counts_per_rev) for d in self.drives
        ]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._consumers, name="sim-epos-hb", daemon=True)

    def start(self) -> SimDriveBus:
        for n in self.nodes:
            n.boot()
        self._thread.start()
        return self

    def _consumers(self) -> None:
        while not self._stop.wait(CONSUMER_CHECK_S):
            for n in self.nodes:
                n.check_master_heartbeat()

    def actual_positions(self) -> list[int]:
        """Motor positions (counts) in cable order."""
        return [round(n.position) for n in self.nodes]

    def node(self, node_id: int) -> SimEpos:
        return next(n for n in self.nodes if n.node_id == node_id)

    def stop(self) -> None:
        self._stop.set()
        for n in self.nodes:
            n.node.nmt.stop_heartbeat()
        if self.device is not None:
            self.device.stop()
            self._dev_bus.shutdown()
        self.network.disconnect()
