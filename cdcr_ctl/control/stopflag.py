"""The loop's stop path that bypasses every queue and lock (issue #21)."""

from __future__ import annotations

from typing import Any

from cdcr_ctl.control.supervisor import Reaction


class StopFlag:
    """The loop's stop path that bypasses every queue and lock (issue #21).

    Any thread (or, over shared memory, another process) calls :meth:`request`; the loop reads
    :attr:`requested` once per cycle, before anything else, and :meth:`acted` records the cycle
    in which the quick stop (or halt) went out. Plain integer stores: no lock a loading or
    planning thread could hold sits on this path. The values live in ``store`` (a 4-slot integer
    array: requested sequence, reaction, acted sequence, acted cycle), so a shared-memory array
    lets another process use the same flag.
    """

    REQUESTED, REACTION, ACTED, ACTED_CYCLE = range(4)

    def __init__(self, store: Any = None) -> None:
        self.store = store if store is not None else [0, 0, 0, -1]

    def request(self, reaction: Reaction) -> int:
        """Ask the loop to stop with ``reaction``; returns the sequence number to wait for."""
        st = self.store
        st[self.REACTION] = int(reaction)
        seq = st[self.REQUESTED] + 1
        st[self.REQUESTED] = seq
        return seq

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
