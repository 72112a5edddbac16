"""An in-process CAN bus between the controller's drive layer and the simulated EPOS nodes, for
lock-step: every frame is delivered the moment it is sent, on the sender's thread.

:class:`HostBus` is the python-can bus the controller's
:class:`~cdcr_ctl.drives.group.DriveGroup` gets; the nodes sit on a canopen ``Network`` over
:class:`NodeBus`. Host -> nodes: ``HostBus.send`` hands the frame to the nodes' network at once
(a SYNC steps every node by its interpolation period and their TPDOs come back inside the same
call). Nodes -> host: the cyclic TPDOs go straight to the group's decoder through the frame hook
(:meth:`HostBus.set_frame_hook`, what :class:`~cdcr_ctl.drives.slcan.SlcanBus` offers), so the
loop's next cycle sees them whatever the machine load; everything else (SDO answers, boot-up,
heartbeats, EMCY) is queued for the group's bus listener thread, as on a real bus.

The bytes are the real ones: the group builds and parses them with the production PDO/SDO code
and the nodes with theirs; only the wire and its timing are gone (a SYNC's answers arrive within
its cycle, as they do on a real bus at these rates).

Heartbeats live on simulated time: a node's producer (canopen's ``send_periodic``, which
:class:`NodeNetwork` overrides) is a :class:`SimPeriodicTask` that :meth:`CanLink.tick` sends
when simulated time passes its due time, handed to the host at once (through the frame hook,
when the host hooked the heartbeats, as the drive group does). As python-can's periodic task,
it sends its first frame when it starts; unlike it, it also sends at once when the node's NMT
state changes (the set-up, during which simulated time stands still, waits for the OPERATIONAL
report; those frames take the listener's way, since they go out while the host is sending).
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import can
import canopen

FrameHook = Callable[[int, bytes, float], None]


def no_cpu_clock() -> float:
    """The CPU clock of the lock-step parts while nobody measures them: always 0 s."""
    return 0.0


class NodeBus(can.BusABC):
    """The nodes' side: what a node sends goes to the host (hooked TPDOs at once, the rest
    queued for the host's listener)."""

    def __init__(self, link: CanLink, **kwargs: Any) -> None:
        self._link = link
        super().__init__(channel="cdcr-lockstep-nodes", **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._link.to_host(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        raise can.CanOperationError("the lock-step link delivers frames to the nodes itself")


class NodeNetwork(canopen.Network):
    """The nodes' canopen network. :meth:`send_message` is canopen's documented hook for a
    custom backend: a hooked TPDO goes to the host's decoder as (COB-ID, bytes) without a
    ``can.Message`` (built and taken apart again for nothing, three times per cycle); every
    other frame takes canopen's way (a Message to :class:`NodeBus`)."""

    def __init__(self, link: CanLink) -> None:
        super().__init__(NodeBus(link))
        self._link = link

    def notify(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """canopen's :meth:`~canopen.Network.notify` (every subscriber of ``can_id`` in order,
        then the node scanner), the scanner called only for a frame it could act on (a node's
        own service, node id not 0): the scanner does nothing with the others (SYNC, RPDOs)."""
        callbacks = self.subscribers.get(can_id)
        if callbacks is not None:
            for callback in callbacks:
                callback(can_id, data, timestamp)
        scanner = self.scanner
        if can_id & 0x7F and (can_id & 0x780) in scanner.SERVICES:
            scanner.on_message_received(can_id)

    def send_periodic(
        self, can_id: int, data: bytes, period: float, remote: bool = False
    ) -> SimPeriodicTask:
        """canopen's periodic transmission (a node's heartbeat producer), on simulated time."""
        return SimPeriodicTask(self._link, can_id, bytes(data), period)

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        link = self._link
        if not remote and link.hook is not None and can_id in link.sync_hooked:
            link.frames_to_host += 1
            clock = link.cpu_clock
            c0 = clock()
            link.hook(can_id, bytes(data), 0.0)
            link.decode_time_s += clock() - c0
            return
        super().send_message(can_id, data, remote)


class HostBus(can.BusABC):
    """The controller's side (give it to :class:`~cdcr_ctl.drives.group.DriveGroup`)."""

    def __init__(self, link: CanLink, **kwargs: Any) -> None:
        self._link = link
        self._queue: queue.SimpleQueue[can.Message] = link.host_queue
        super().__init__(channel="cdcr-lockstep", **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._link.to_nodes(msg)

    def send_frames(
        self, frames: Sequence[tuple[int, bytes]], timeout: float | None = None
    ) -> None:
        """A cycle's burst of standard data frames (id, data), in order (the group's burst
        path, as :meth:`~cdcr_ctl.drives.slcan.SlcanBus.send_frames`): each handled by the
        nodes now, without a ``can.Message`` per frame."""
        self._link.burst_to_nodes(frames)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            return self._queue.get(timeout=timeout), False
        except queue.Empty:
            return None, False

    def set_frame_hook(self, can_ids: Sequence[int], hook: FrameHook) -> None:
        """Hand these COB-IDs (the cyclic TPDOs, the heartbeats) to ``hook(can_id, data, t)``
        without a Message, on the sender's thread (heartbeats: those :meth:`CanLink.tick`
        sends)."""
        link = self._link
        link.hooked = frozenset(can_ids)
        link.sync_hooked = frozenset(c for c in link.hooked if not _is_heartbeat(c))
        link.hook = hook


class CanLink:
    """The two ends of the lock-step bus and the nodes' canopen network.

    ``node_time_s`` (s, CPU of the nodes' handling, the decoding of their answers excluded) and
    ``decode_time_s`` (s, CPU of the host's TPDO decoding) are for the benchmark: they count
    only while ``cpu_clock`` is ``time.thread_time`` (the default reads no clock: a
    thread-CPU clock is a system call, ~1.5 us, and this runs for every frame).
    """

    def __init__(self) -> None:
        self.host_queue: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self.hooked: frozenset[int] = frozenset()
        #: The hooked COB-IDs handed over whenever a node sends them (all but heartbeats: a
        #: node's boot-up or NMT state report goes out while the host is sending its command,
        #: and a handler that answers it would wait for the host's own send lock).
        self.sync_hooked: frozenset[int] = frozenset()
        self.hook: FrameHook | None = None
        #: Simulated time (s): the rig's clock (the periodic tasks' due times are on it).
        self.clock: Callable[[], float] = no_cpu_clock
        self._periodic: list[SimPeriodicTask] = []
        self.host = HostBus(self)
        self.network = NodeNetwork(self)
        self.node_bus = self.network.bus
        self._lock = threading.RLock()
        self.node_time_s = 0.0
        self.decode_time_s = 0.0
        self.frames_to_nodes = 0
        self.frames_to_host = 0
        self.cpu_clock: Callable[[], float] = no_cpu_clock

    def to_nodes(self, msg: can.Message) -> None:
        """A frame from the host, handled by every node now (as canopen's listener would)."""
        if msg.is_error_frame or msg.is_remote_frame:
            return
        clock = self.cpu_clock
        c0 = clock()
        d0 = self.decode_time_s
        with self._lock:
            self.frames_to_nodes += 1
            self.network.notify(msg.arbitration_id, bytearray(msg.data), 0.0)
        self.node_time_s += clock() - c0 - (self.decode_time_s - d0)

    def burst_to_nodes(self, frames: Sequence[tuple[int, bytes]]) -> None:
        """Standard data frames from the host, in order, each handled by every node now."""
        clock = self.cpu_clock
        c0 = clock()
        d0 = self.decode_time_s
        notify = self.network.notify
        with self._lock:
            for can_id, data in frames:
                self.frames_to_nodes += 1
                notify(can_id, bytearray(data), 0.0)
        self.node_time_s += clock() - c0 - (self.decode_time_s - d0)

    def tick(self, t_s: float) -> None:
        """Simulated time has reached ``t_s``: every periodic frame due by then goes out (a node
        that is silent or stopped its producer sends nothing). Call it where no host lock is
        held (the rig's world advance, on the loop thread)."""
        for task in list(self._periodic):
            while task.next_s <= t_s and task.running:
                task.next_s += task.period_s
                self.periodic_frame(task.can_id, task.data)

    def periodic_frame(self, can_id: int, data: bytes) -> None:
        """One periodic frame from a node, handed to the host's hook at once when hooked."""
        hook = self.hook
        if hook is not None and can_id in self.hooked:
            self.frames_to_host += 1
            hook(can_id, data, 0.0)
            return
        self.network.send_message(can_id, data)

    def to_host(self, msg: can.Message) -> None:
        """A frame from a node: hooked TPDOs decoded now, the rest queued for the listener."""
        self.frames_to_host += 1
        hook = self.hook
        if hook is not None and msg.arbitration_id in self.sync_hooked:
            clock = self.cpu_clock
            c0 = clock()
            hook(msg.arbitration_id, bytes(msg.data), 0.0)
            self.decode_time_s += clock() - c0
            return
        self.host_queue.put(
            can.Message(
                arbitration_id=msg.arbitration_id,
                data=bytes(msg.data),
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                timestamp=time.time(),
            )
        )


def _is_heartbeat(can_id: int) -> bool:
    """Whether ``can_id`` is a node's NMT error-control COB-ID (0x701-0x77F: heartbeat, boot-up)."""
    return 0x700 < can_id < 0x780


class SimPeriodicTask:
    """A node's periodic frame on simulated time (what canopen's ``send_periodic`` returns:
    :meth:`stop`, :meth:`update`), sent by :meth:`CanLink.tick`. It sends its first frame at
    once, then every ``period_s`` of simulated time; :meth:`update` with new data sends it at
    once too (module docstring)."""

    def __init__(self, link: CanLink, can_id: int, data: bytes, period_s: float) -> None:
        self._link = link
        self.can_id = can_id
        self.data = data
        self.period_s = float(period_s)
        self.running = True
        self.next_s = link.clock() + self.period_s
        link._periodic.append(self)
        link.network.send_message(can_id, data)

    def stop(self) -> None:
        self.running = False
        with contextlib.suppress(ValueError):
            self._link._periodic.remove(self)

    def update(self, data: bytes) -> None:
        new = bytes(data)
        if new != self.data:
            self.data = new
            if self.running:
                self._link.network.send_message(self.can_id, new)


__all__ = ["CanLink", "HostBus", "NodeBus", "NodeNetwork", "SimPeriodicTask"]
