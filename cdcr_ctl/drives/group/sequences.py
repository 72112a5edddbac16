"""The drive group's sequences (off the loop's path, blocking, with named timeouts): controlword
commands (quick stop, disable, halt, resume), the CiA 402 walk to OPERATION ENABLED, fault
reset, homing (0x6098) and profile-position moves, each step confirmed from TPDO feedback.

A mixin of :class:`~cdcr_ctl.drives.group.facade.DriveGroup` (the state lives on the group).
"""

from __future__ import annotations

import dataclasses
import logging
import struct
import time
from collections.abc import Callable, Sequence

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import (
    CW_CHANGE_IMMEDIATELY_BIT,
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_FAULT_RESET,
    CW_HALT_BIT,
    CW_HOMING_START_BIT,
    CW_NEW_SETPOINT_BIT,
    CW_QUICK_STOP,
    SW_HOMING_ATTAINED,
    SW_HOMING_ERROR,
    SW_SETPOINT_ACK,
    SW_TARGET_REACHED,
    Mode,
    State,
    next_controlword,
)
from cdcr_ctl.drives.epos import controlword_payload, pp_setpoint_payload
from cdcr_ctl.drives.group.common import (
    FAULT_RESET_TIMEOUT_S,
    IDLE_PERIODS,
    MOVE_TIMEOUT_S,
    SETPOINT_ACK_TIMEOUT_S,
    STATE_STEP_TIMEOUT_S,
    TPDO_MISSES,
    SequenceDeadline,
    _Drive,
    sdo_controlword_request,
)
from cdcr_ctl.drives.heartbeat import NMT_OPERATIONAL
from cdcr_ctl.errors import CommError, DriveFault, RigError, RigTimeoutError

#: One logger for the whole group (the name it had before the group was split up).
log = logging.getLogger("cdcr_ctl.drives.group")


class _Sequences:
    """CiA 402 sequences for :class:`~cdcr_ctl.drives.group.facade.DriveGroup`."""

    def _send_controlword(self, d: _Drive, cw: int) -> None:
        with self._cycle_lock:
            d.controlword = cw
            self._send(d.layout.controlword.cob_id, controlword_payload(cw))

    def quick_stop_all(self) -> None:
        """Controlword 0x0002 (quick stop) to every drive now, by RPDO; a drive whose heartbeat
        says it is not OPERATIONAL (PDOs do not reach it) gets it by an SDO write too (sent
        without waiting for the answer). Never raises (best effort on a broken bus)."""
        if self._closed:
            return
        with self._cycle_lock:
            if self.quick_stop_at_sync is None:
                self.quick_stop_at_sync = self.sync_count
            for d in self._drives:
                d.reset_stream()
                try:
                    self._send_controlword(d, CW_QUICK_STOP)
                    nmt = self._heartbeats.state(d.id)
                    if nmt is not None and nmt != NMT_OPERATIONAL:
                        self._send(0x600 + d.id, sdo_controlword_request(CW_QUICK_STOP))
                except (CommError, RigError):
                    log.error("quick stop to node %d could not be sent", d.id)

    quick_stop = quick_stop_all

    def disable_all(self) -> None:
        """Controlword 0x0000 (disable voltage: power stage off, SWITCH ON DISABLED) to every
        drive; valid from every state but FAULT. Never raises."""
        if self._closed:
            return
        with self._cycle_lock:
            for d in self._drives:
                d.reset_stream()
                try:
                    self._send_controlword(d, CW_DISABLE_VOLTAGE)
                except (CommError, RigError):
                    log.error("disable to node %d could not be sent", d.id)

    disable = disable_all

    def halt_all(self) -> None:
        """Set the halt bit (8): every drive decelerates on its profile deceleration and holds."""
        with self._cycle_lock:
            for d in self._drives:
                self._send_controlword(d, d.controlword | CW_HALT_BIT)

    def resume_all(self) -> None:
        """Clear the halt bit."""
        with self._cycle_lock:
            for d in self._drives:
                self._send_controlword(d, d.controlword & ~CW_HALT_BIT)

    def _require_started(self) -> None:
        if not self._started:
            raise RigError("drives are not configured: call boot() and configure() first")
        if self._closed:
            raise RigError("the drive group is closed")

    def _require_no_fault(self) -> None:
        f = self._fault
        if f is not None:
            err = f.error()
            err.add_note("reset_faults() first")
            raise err

    def _deadline(self, timeout_s: float) -> SequenceDeadline:
        """A wait's timeout on the drives' time (the watch clock), backstopped on the clock."""
        return SequenceDeadline(timeout_s, self.watch_clock, self.clock)

    def _await_feedback(self, max_wait_s: float) -> None:
        """Wait for the next TPDO (at most ``max_wait_s``, and a SYNC period, of wall time);
        clock SYNC if no cycle runs, at most one per period of wall time."""
        now = self.clock()
        if (
            now - self._last_cycle_s > IDLE_PERIODS * self.period_s
            and now >= self._next_self_sync_s
        ):
            self._next_self_sync_s = now + self.period_s
            if self._sync_source is not None:
                self._sync_source()
            else:
                self.send_sync()
        with self._fb_cond:
            self._fb_waiters += 1
            try:
                self._fb_cond.wait(min(max_wait_s, self.period_s))
            finally:
                self._fb_waiters -= 1

    def _wait_for(
        self,
        drives: Sequence[_Drive],
        done: Callable[[_Drive], bool],
        timeout_s: float,
        what: str,
        after_sync: int | None = None,
    ) -> None:
        """Wait until ``done(d)`` for every drive, on feedback newer than SYNC ``after_sync``;
        ``timeout_s`` on the drives' time (:meth:`_deadline`)."""
        deadline = self._deadline(timeout_s)
        while True:
            self._require_no_fault()
            late = [
                d
                for d in drives
                if not (after_sync is None or d.tpdo_sync > after_sync) or not done(d)
            ]
            if not late:
                return
            why = deadline.expired()
            if why is not None:
                d = late[0]
                raise RigTimeoutError(
                    f"node {d.id}: {what} not confirmed within {timeout_s} s (state "
                    f"{d.feedback.state.value}, statusword 0x{d.feedback.statusword:04X}){why}"
                )
            self._await_feedback(deadline.left_s())

    def _walk(self, target: State, step_timeout_s: float) -> None:
        """Step every drive through the 402 diagram to ``target``, all drives at once; each
        step must show in the statusword within ``step_timeout_s`` of the drives' time
        (:meth:`_deadline`)."""
        self._require_started()
        sent: dict[int, tuple[State, int]] = {}
        last_states = [d.feedback.state for d in self._drives]
        deadline = self._deadline(step_timeout_s)
        while True:
            self._require_no_fault()
            states = [d.feedback.state for d in self._drives]
            if all(s is target for s in states):
                return
            if states != last_states:
                deadline.restart()
                last_states = states
            with self._cycle_lock:
                self._require_no_fault()
                for d, s in zip(self._drives, states, strict=True):
                    if s is State.FAULT:
                        code = d.last_emcy.code if d.last_emcy else 0
                        raise DriveFault(
                            d.id,
                            code,
                            f"in FAULT ({d.fault_text or 'no EMCY'}): reset_faults() first",
                        )
                    cw = next_controlword(s, target)
                    if cw is not None and sent.get(d.id) != (s, cw):
                        self._send_controlword(d, cw)
                        sent[d.id] = (s, cw)
            why = deadline.expired()
            if why is not None:
                late = [d for d in self._drives if d.feedback.state is not target]
                d = late[0]
                raise RigTimeoutError(
                    f"node {d.id}: still {d.feedback.state.value} {step_timeout_s} s after "
                    f"controlword 0x{d.controlword:04X} on the way to {target.value}{why}"
                )
            self._await_feedback(deadline.left_s())

    def enable(self, timeout_s: float = STATE_STEP_TIMEOUT_S) -> None:
        """Every drive to OPERATION ENABLED: controlwords 0x06, 0x07, 0x0F as each needs, all
        drives at once, each step confirmed by the statusword within ``timeout_s``."""
        self._walk(State.OPERATION_ENABLED, timeout_s)
        for d in self._drives:
            d.reset_stream()

    def reset_faults(self, timeout_s: float = FAULT_RESET_TIMEOUT_S) -> list[str]:
        """Fault reset (controlword 0x80 rising edge) of every drive in FAULT, confirmed by its
        statusword leaving FAULT within ``timeout_s`` of the drives' time; then check every drive
        answers (TPDO and heartbeat) and clear the latched fault. A drive that rebooted since
        configuration is reconfigured first (:meth:`reconfigure`). Returns what was done beyond
        the reset, one line per drive (the reconfigured ones). Raises DriveFault naming the node
        when a reset does not take, a reconfiguration fails or a drive does not answer."""
        self._require_started()
        notes = []
        for node in self.rebooted_nodes:
            try:
                notes.append(self.reconfigure(node))
            except RigError as exc:
                raise DriveFault(
                    node, 0, f"rebooted and lost its configuration; reconfiguring failed: {exc}"
                ) from exc
        faulted = [
            d
            for d in self._drives
            # FAULT in its feedback, or an EMCY whose FAULT statusword is still on its way (the
            # drive samples its statusword at the SYNC: the feedback lags a cycle)
            if d.feedback.state in (State.FAULT, State.FAULT_REACTION_ACTIVE)
            or d.last_emcy is not None
        ]
        with self._cycle_lock:
            for d in faulted:
                self._send_controlword(d, CW_DISABLE_VOLTAGE)
                self._send_controlword(d, CW_FAULT_RESET)
            start = self.sync_count
        deadline = self._deadline(timeout_s)

        def still_faulted(d: _Drive) -> bool:
            # confirmed only by feedback sampled at a SYNC sent after the reset
            faulty = d.feedback.state in (State.FAULT, State.FAULT_REACTION_ACTIVE)
            return faulty or d.tpdo_sync <= start

        while any(still_faulted(d) for d in faulted):
            why = deadline.expired()
            if why is not None:
                d = next(d for d in faulted if still_faulted(d))
                code = d.last_emcy.code if d.last_emcy else 0
                raise DriveFault(
                    d.id,
                    code,
                    f"fault reset not confirmed: still FAULT {timeout_s} s after controlword "
                    f"0x0080 ({d.fault_text or 'no EMCY'}){why}",
                )
            self._await_feedback(deadline.left_s())
        with self._cycle_lock:
            for d in faulted:
                self._send_controlword(d, CW_DISABLE_VOLTAGE)
        now = self.clock()
        for d in self._drives:
            if (
                self.sync_count - d.tpdo_sync > TPDO_MISSES
                and now - d.last_tpdo_s > self.feedback_timeout_s
            ):
                raise DriveFault(
                    d.id,
                    0,
                    f"not answering (no TPDO for {now - d.last_tpdo_s:.3f}"
                    " s); cannot clear the fault",
                )
        for node, age in self._heartbeats.expired(self.watch_clock()):
            raise DriveFault(node, 0, f"no heartbeat for {age:.3f} s; cannot clear the fault")
        with self._fault_lock:
            self._fault = None
            self.fault_at_sync = None
            self.quick_stop_at_sync = None
            for d in self._drives:
                d.fault_text, d.last_emcy, d.fault_tpdos = "", None, 0
                d.feedback = dataclasses.replace(d.feedback, fault="")
                d.reset_stream()
        return notes

    def home(
        self, sync: Callable[[], None] | None = None, timeout_s: float | None = None
    ) -> list[int]:
        """Home every drive with its 0x6098 method; return the actual positions after homing, in
        the group's order. Drives that are not enabled are enabled for homing and disabled again
        afterwards (the power state is left as found).

        ``sync`` sends one SYNC (and whatever else the caller's cycle needs) so TPDO feedback
        keeps coming; by default the group sends SYNCs itself at the configured period. The
        caller's loop must not send set-points meanwhile. The drives return to their configured
        mode afterwards (confirmed by 0x6061).
        """
        self._require_started()
        self._require_no_fault()
        self._sync_source = sync
        was_enabled = all(d.feedback.state is State.OPERATION_ENABLED for d in self._drives)
        try:
            for d in self._drives:
                for w in epos.homing_writes(d.cfg):
                    self._sdo_write(d, w)
                self._set_mode(d, Mode.HOMING)
            self._walk(State.OPERATION_ENABLED, STATE_STEP_TIMEOUT_S)
            with self._cycle_lock:
                for d in self._drives:
                    self._send_controlword(d, CW_ENABLE_OPERATION)
                    self._send_controlword(d, CW_ENABLE_OPERATION | CW_HOMING_START_BIT)
                start = self.sync_count
            limit = timeout_s or max(d.cfg.homing.timeout_s for d in self._drives)

            def homed(d: _Drive) -> bool:
                sw = d.feedback.statusword
                if sw & SW_HOMING_ERROR:
                    raise DriveFault(
                        d.id,
                        0,
                        f"homing error (statusword 0x{sw:04X}, bit 13), "
                        f"method {d.cfg.homing.method}",
                    )
                return bool(sw & SW_HOMING_ATTAINED and sw & SW_TARGET_REACHED)

            self._wait_for(self._drives, homed, limit, "homing", after_sync=start)
            with self._cycle_lock:
                for d in self._drives:
                    self._send_controlword(d, CW_ENABLE_OPERATION)
            for d in self._drives:
                self._set_mode(d, d.mode)
                d.reset_stream()
            after = self.sync_count
            self._wait_for(self._drives, lambda d: True, STATE_STEP_TIMEOUT_S, "feedback", after)
            if not was_enabled:
                self.disable_all()
            return [d.feedback.position_counts for d in self._drives]
        finally:
            self._sync_source = None

    def _set_mode(self, d: _Drive, mode: Mode) -> None:
        self._sdo_write(
            d,
            epos.SdoWrite(
                epos.MODES_OF_OPERATION, 0, struct.pack("<b", mode), "modes of operation"
            ),
        )
        deadline = self.clock() + STATE_STEP_TIMEOUT_S
        while True:
            shown = struct.unpack("<b", self._sdo_read(d, epos.MODES_DISPLAY, 0)[:1])[0]
            if shown == int(mode):
                return
            if self.clock() > deadline:
                raise RigTimeoutError(
                    f"node {d.id}: 0x6061 shows mode {shown}, not {int(mode)} ({mode.name}), "
                    f"{STATE_STEP_TIMEOUT_S} s after writing 0x6060"
                )
            time.sleep(self.period_s)

    def move_to(
        self, targets_counts: Sequence[int], timeout_s: float = MOVE_TIMEOUT_S
    ) -> list[int]:
        """Profile-position move of every drive to ``targets_counts`` (blocking, not for the
        loop's path): new set-point with bit 4, acknowledged by statusword bit 12, then wait for
        target reached (bit 10). Drives must be OPERATION ENABLED in mode ``pp``. Returns the
        actual positions."""
        self._require_started()
        self._require_no_fault()
        for d in self._drives:
            if d.mode is not Mode.PROFILE_POSITION:
                raise DriveFault(d.id, 0, f"move_to needs profile position mode, not {d.cfg.mode}")
            if d.feedback.state is not State.OPERATION_ENABLED:
                raise DriveFault(
                    d.id,
                    0,
                    f"move_to needs OPERATION ENABLED, not "
                    f"{d.feedback.state.value}: enable() first",
                )
        bits = CW_NEW_SETPOINT_BIT | CW_CHANGE_IMMEDIATELY_BIT
        with self._cycle_lock:
            for d, t in zip(self._drives, targets_counts, strict=True):
                d.controlword = CW_ENABLE_OPERATION
                self._send(
                    d.layout.setpoint.cob_id, pp_setpoint_payload(int(t), d.controlword | bits)
                )
                d.last_target, d.pp_pending = int(t), True
            start = self.sync_count
        self._wait_for(
            self._drives,
            lambda d: bool(d.feedback.statusword & SW_SETPOINT_ACK),
            SETPOINT_ACK_TIMEOUT_S,
            "set-point acknowledge",
            after_sync=start,
        )
        with self._cycle_lock:
            for d in self._drives:
                self._send(
                    d.layout.setpoint.cob_id, pp_setpoint_payload(d.last_target or 0, d.controlword)
                )
                d.pp_pending = False
            start = self.sync_count
        self._wait_for(
            self._drives,
            lambda d: (
                bool(d.feedback.statusword & SW_TARGET_REACHED)
                and not d.feedback.statusword & SW_SETPOINT_ACK
            ),
            timeout_s,
            "target reached",
            after_sync=start,
        )
        return [d.feedback.position_counts for d in self._drives]
