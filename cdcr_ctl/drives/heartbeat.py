"""Heartbeat consumer on the master (CiA 301 7.2.8.3.2.2): has every drive beaten recently?

Pure bookkeeping on an injected clock value: the bus listener calls :meth:`HeartbeatConsumer.beat`
for every heartbeat frame (COB-ID 0x700 + node, one byte: the NMT state), the cycle (or a watchdog
when no cycle runs) calls :meth:`HeartbeatConsumer.expired` with the present time. A node expires
when no heartbeat came for ``factor`` times its producer time (0x1017). Once armed (after the
drives were started), a boot-up (state 0) or a drive leaving OPERATIONAL is an anomaly too: the
drive restarted or was reset behind the master's back.

Frames in flight around an NMT command: a node's CAN controller may hold a heartbeat queued
before the node processed the master's NMT command, so it leaves after it (a PRE-OPERATIONAL
report a fraction of a millisecond after ``NMT start``). After :meth:`HeartbeatConsumer.commanded`
a node's reports other than the commanded state are not anomalies until the node has reported
that state or one producer period has passed, whichever is first; after that, leaving the state
is the anomaly it always was.

Cost per check: :meth:`HeartbeatConsumer.overdue` is O(1) while no deadline has passed. It keeps
the earliest deadline it knows (a lower bound: heartbeats only move deadlines later) and scans the
nodes only when that bound has passed, which happens about once per producer period per node,
so a 1 kHz cycle can check every SYNC.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping

#: NMT states in heartbeat frames (CiA 301).
NMT_BOOTUP = 0x00
NMT_STOPPED = 0x04
NMT_OPERATIONAL = 0x05
NMT_PRE_OPERATIONAL = 0x7F
NMT_STATE_NAMES = {
    NMT_BOOTUP: "boot-up",
    NMT_STOPPED: "STOPPED",
    NMT_OPERATIONAL: "OPERATIONAL",
    NMT_PRE_OPERATIONAL: "PRE-OPERATIONAL",
}
#: A heartbeat is missing after this many producer periods.
HEARTBEAT_TIMEOUT_FACTOR = 3.0


class HeartbeatConsumer:
    """Last heartbeat time and NMT state per node; ``producer_times_s`` 0 means not watched."""

    def __init__(
        self, producer_times_s: Mapping[int, float], factor: float = HEARTBEAT_TIMEOUT_FACTOR
    ) -> None:
        self.timeouts_s = {n: factor * t for n, t in producer_times_s.items() if t > 0}
        self.periods_s = {n: t for n, t in producer_times_s.items() if t > 0}
        #: node -> (commanded NMT state, end of the window for reports sent before it) (s).
        self._settling: dict[int, tuple[int, float]] = {}
        self._last_s: dict[int, float] = {}
        self._state: dict[int, int] = {}
        self._armed = False
        self._lock = threading.Lock()
        #: No node's deadline is before this (s); see the module docstring.
        self._earliest_s = float("inf")

    def arm(self, now_s: float) -> None:
        """Start watching: every node gets one full timeout from ``now_s`` to beat."""
        with self._lock:
            for n in self.timeouts_s:
                self._last_s[n] = max(self._last_s.get(n, now_s), now_s)
            self._armed = True
            self._earliest_s = self._earliest_deadline()

    def commanded(self, node: int, nmt_state: int, now_s: float) -> None:
        """The master just sent ``node`` an NMT command to enter ``nmt_state`` at ``now_s``:
        reports of another state sent before the node acted on it may still arrive, for up to
        one producer period (see the module docstring)."""
        period = self.periods_s.get(node)
        if period is None:
            return
        with self._lock:
            self._settling[node] = (nmt_state, now_s + period)

    def settling(self, node: int, now_s: float) -> bool:
        """Whether ``node`` is inside the window after an NMT command and has not reported the
        commanded state yet (a report of another state now is one sent before the command)."""
        window = self._settling.get(node)
        return window is not None and now_s <= window[1]

    def disarm(self) -> None:
        with self._lock:
            self._armed = False

    @property
    def armed(self) -> bool:
        return self._armed

    def beat(self, node: int, nmt_state: int, now_s: float) -> str | None:
        """Record a heartbeat; returns the anomaly text when an armed node restarted or left
        OPERATIONAL, else None."""
        state = nmt_state & 0x7F
        with self._lock:
            self._last_s[node] = now_s
            window = self._settling.get(node)
            if window is not None and (state == window[0] or now_s > window[1]):
                del self._settling[node]  # the command took effect, or its window passed
                window = None
            if window is not None:
                # A report sent before the node acted on the command: not its state now.
                return None
            old = self._state.get(node)
            self._state[node] = state
            armed = self._armed and node in self.timeouts_s
        if not armed or state == NMT_OPERATIONAL:
            return None
        if state == NMT_BOOTUP:
            return "boot-up message: the drive restarted"
        if old != state:
            return f"NMT state changed to {NMT_STATE_NAMES.get(state, hex(state))}"
        return None

    def _earliest_deadline(self) -> float:
        return min(
            (self._last_s.get(n, float("-inf")) + t for n, t in self.timeouts_s.items()),
            default=float("inf"),
        )

    def deadline_s(self, node: int) -> float:
        """When ``node``'s heartbeat is due at the latest (s, the beats' clock)."""
        return self._last_s.get(node, float("-inf")) + self.timeouts_s.get(node, float("inf"))

    def overdue(self, now_s: float) -> list[tuple[int, float]]:
        """:meth:`expired`, in O(1) while the earliest known deadline has not passed."""
        if not self._armed or now_s <= self._earliest_s:
            return []
        with self._lock:
            self._earliest_s = self._earliest_deadline()
        if now_s <= self._earliest_s:
            return []
        return self.expired(now_s)

    def state(self, node: int) -> int | None:
        """Last NMT state the node reported (None before its first heartbeat)."""
        return self._state.get(node)

    def age_s(self, node: int, now_s: float) -> float:
        return now_s - self._last_s.get(node, float("-inf"))

    def expired(self, now_s: float) -> list[tuple[int, float]]:
        """(node, age_s) of every armed node whose heartbeat is overdue."""
        if not self._armed:
            return []
        with self._lock:
            return [
                (n, now_s - self._last_s.get(n, float("-inf")))
                for n, limit in self.timeouts_s.items()
                if now_s - self._last_s.get(n, float("-inf")) > limit
            ]
