"""The loop's stop path that bypasses every queue and lock (issue #21)."""

from __future__ import annotations

from typing import Any

from cdcr_ctl.control.supervisor import Reaction


class StopFlag:
    """The loop's stop path that bypasses every queue and lock (issue #21).

    Any thread (or, over shared memory, another process) calls :meth:`request`; the loop reads
    :attr:`requested` once per cycle, before anything else, and :meth:`acted` records the cycle
    in which the quick stop (or halt) went out. Plain integer stores: no lock a loading or
    planning thread could hold sits on this path. The values live in ``store`` (an integer array
    of :data:`SLOTS` slots: requested sequence, reaction, acted sequence, acted cycle, the loop's
    current cycle), so a shared-memory array (``multiprocessing.RawArray("q", SLOTS)``, acted
    cycle -1) lets another process use the same flag: the daemon's front process
    (:mod:`cdcr_ctl.daemon.front`) raises it for the rig process's loop.

    The loop writes its cycle counter with :meth:`tick` every cycle, so a requester in another
    process knows the cycle its request arrived in (``cycles_waited``) without asking the loop.
    """

    REQUESTED, REACTION, ACTED, ACTED_CYCLE, CYCLE = range(5)
    SLOTS = 5

    def __init__(self, store: Any = None) -> None:
        self.store = store if store is not None else [0, 0, 0, -1, 0]

    def request(self, reaction: Reaction) -> int:
        """Ask the loop to stop with ``reaction``; returns the sequence number to wait for."""
        st = self.store
        st[self.REACTION] = int(reaction)
        seq = st[self.REQUESTED] + 1
        st[self.REQUESTED] = seq
        return seq

    def tick(self, cycle: int) -> None:
        """(loop) The cycle now running."""
        self.store[self.CYCLE] = cycle

    @property
    def cycle(self) -> int:
        """The loop's cycle counter as of its last :meth:`tick`."""
        return self.store[self.CYCLE]

    @property
    def requested(self) -> int:
        return self.store[self.REQUESTED]

    def acted(self, seq: int, cycle: int) -> None:
        self.store[self.ACTED_CYCLE] = cycle
        self.store[self.ACTED] = seq

    def acted_cycle(self, seq: int) -> int | None:
        """The loop cycle that acted on request ``seq`` (or a later one), None while pending."""
        st = self.store
        return st[self.ACTED_CYCLE] if st[self.ACTED] >= seq else None


__all__ = ["StopFlag"]
