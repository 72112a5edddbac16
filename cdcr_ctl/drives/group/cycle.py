"""The drive group's cycle, the loop's path: plan each drive's set-point RPDO (pure, from the
mode's stream state), send them and SYNC as one burst, then run the supervision checks; the
latest feedback per drive.

A mixin of :class:`~cdcr_ctl.drives.group.facade.DriveGroup` (the state lives on the group).
"""

from __future__ import annotations

from collections.abc import Sequence

from cdcr_ctl.drives.cia402 import (
    CW_CHANGE_IMMEDIATELY_BIT,
    CW_ENABLE_OPERATION,
    CW_IP_ENABLE_BIT,
    CW_NEW_SETPOINT_BIT,
    Mode,
    State,
)
from cdcr_ctl.drives.epos import (
    controlword_payload,
    counts_per_s_to_rpm,
    pp_setpoint_payload,
    pvt_payload,
    target_payload,
)
from cdcr_ctl.drives.group.common import _SYNC_FRAME, IP_PREFILL_POINTS, SYNC_COB_ID, Feedback
from cdcr_ctl.errors import CommError

#: Modes whose set-point is one synchronous target RPDO per cycle (a module global: read faster
#: than a tuple of the enum's attributes built every cycle).
_SYNC_TARGET_MODES = (Mode.CYCLIC_SYNC_POSITION, Mode.POSITION_MODE)


class _Cycle:
    """Plan and send for :class:`~cdcr_ctl.drives.group.facade.DriveGroup`."""

    def _plan(self, targets_counts: Sequence[int]) -> tuple[list[tuple[int, bytes]], list[tuple]]:
        """Frames of one cycle (without SYNC) and each drive's stream state after it. Pure."""
        frames: list[tuple[int, bytes]] = []
        states: list[tuple] = []
        faulted = self._fault is not None
        period_ms = round(self.period_s * 1e3)
        for d, t in zip(self._drives, targets_counts, strict=True):
            t = int(t)
            last, pending, points, active = d.last_target, d.pp_pending, d.ip_points, d.ip_active
            cob = d.layout.setpoint.cob_id
            if d.mode in _SYNC_TARGET_MODES:
                # A synchronous target: one RPDO, no stream state but the last target.
                frames.append((cob, target_payload(t)))
                states.append((t, pending, points, active))
                continue
            enabled = (
                not faulted
                and d.feedback.state is State.OPERATION_ENABLED
                and d.controlword & 0x8F == CW_ENABLE_OPERATION
            )
            if d.mode is Mode.PROFILE_POSITION:
                cw = d.controlword & ~(CW_NEW_SETPOINT_BIT | CW_CHANGE_IMMEDIATELY_BIT)
                if not enabled:
                    last, pending = None, False
                elif pending:
                    frames.append((cob, pp_setpoint_payload(last or 0, cw)))
                    pending = False
                elif t != last:
                    bits = CW_NEW_SETPOINT_BIT | CW_CHANGE_IMMEDIATELY_BIT
                    frames.append((cob, pp_setpoint_payload(t, cw | bits)))
                    last, pending = t, True
            elif d.mode is Mode.INTERPOLATED_POSITION:
                if not enabled:
                    last, points, active = None, 0, False
                else:
                    v = 0 if last is None else (t - last) / self.period_s
                    rpm = counts_per_s_to_rpm(v, d.cfg.encoder_counts_per_rev)
                    frames.append((cob, pvt_payload(t, rpm, period_ms)))
                    last, points = t, points + 1
                    if not active and points >= IP_PREFILL_POINTS:
                        cw = d.controlword | CW_IP_ENABLE_BIT
                        frames.append((d.layout.controlword.cob_id, controlword_payload(cw)))
                        active = True
            states.append((last, pending, points, active))
        return frames, states

    def build_cycle(self, targets_counts: Sequence[int]) -> list[tuple[int, bytes]]:
        """(COB-ID, data) of every frame of one cycle: the set-point RPDOs, then SYNC. Pure: it
        neither sends nor changes the group. ``targets_counts`` in the group's drive order."""
        frames, _ = self._plan(targets_counts)
        return [*frames, _SYNC_FRAME]

    def send_cycle(self, targets_counts: Sequence[int]) -> None:
        """Send one cycle's set-points as one burst, then SYNC; then check feedback and heartbeat
        ages. Never blocks on an answer; a send failure is latched as a fault, not raised."""
        if self._closed:
            return
        now = self.clock()
        with self._cycle_lock:
            self._send_pending_quick_stop()
            frames, states = self._plan(targets_counts)
            frames.append(_SYNC_FRAME)
            self._sync_starts(now)
            try:
                self._send_burst(frames)
            except CommError:
                return
            for d, (last, pending, points, active) in zip(self._drives, states, strict=True):
                d.last_target, d.pp_pending, d.ip_points = last, pending, points
                if active and not d.ip_active:
                    d.controlword |= CW_IP_ENABLE_BIT
                d.ip_active = active
            self.sync_count += 1
            self._sync_times.append((self.sync_count, now))
            self._last_cycle_s = now
        self._supervise(now)

    def send_sync(self) -> None:
        """One SYNC alone (non-cyclic phases still need TPDO feedback); then the same checks."""
        if self._closed:
            return
        now = self.clock()
        with self._cycle_lock:
            self._send_pending_quick_stop()
            self._sync_starts(now)
            try:
                self._send(SYNC_COB_ID, b"")
            except CommError:
                return
            self.sync_count += 1
            self._sync_times.append((self.sync_count, now))
        self._supervise(self.clock())

    def _sync_starts(self, now: float) -> None:
        """Before each SYNC (cycle lock held): when no SYNC went out for longer than the feedback
        timeout (start-up, homing by the caller, a paused loop), no TPDO was due meanwhile, so
        each drive's silence counts from this SYNC. Otherwise a cycle that starts later than
        that after :meth:`configure` would find every drive "not answering" before its first
        TPDO had time to come back (over slcan to another process: a few ms)."""
        if now - self._last_sync_s > self.feedback_timeout_s:
            for d in self._drives:
                d.tpdo_sync = self.sync_count
                d.last_tpdo_s = max(d.last_tpdo_s, now)
            self._oldest_tpdo_sync = self.sync_count
        self._last_sync_s = now

    def _send_pending_quick_stop(self) -> None:
        """A fault seen by another thread whose quick stop has not gone out yet (that thread
        waits for the cycle lock): send it now, before this SYNC (cycle lock held)."""
        pending = self._fault is not None and self.quick_stop_at_sync is None
        if pending and self._started and self.react_to_faults:
            self.quick_stop_all()

    def feedback(self) -> list[Feedback]:
        """Latest feedback per drive, in the group's order (never blocks)."""
        return [d.feedback for d in self._drives]

    @property
    def node_ids(self) -> list[int]:
        return [d.id for d in self._drives]

    def tpdo_counts(self) -> list[int]:
        """TPDOs received per drive since the group was made (statistics)."""
        return [d.tpdo_count for d in self._drives]
