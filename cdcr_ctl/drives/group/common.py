"""What every part of the drive group shares: the named timeouts and counts, the COB-IDs it sends
(SYNC, NMT), the records it hands out (:class:`Feedback`, :class:`GroupFault`) and the
per-drive bookkeeping (:class:`_Drive`). No I/O.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import canopen

from cdcr_ctl.config.drives import DriveConfig
from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import CW_DISABLE_VOLTAGE, MODE_BY_NAME, State
from cdcr_ctl.drives.emcy import Emcy
from cdcr_ctl.errors import CommError, DriveFault, RigError

SYNC_COB_ID = 0x080
NMT_COB_ID = 0x000
NMT_START, NMT_PRE_OPERATIONAL, NMT_RESET_COMMUNICATION = 0x01, 0x80, 0x82
#: Wait for each node's boot-up message after an NMT reset communication (s).
BOOT_TIMEOUT_S = 5.0
#: SDO request timeout (s); one retry follows (canopen's SdoClient).
SDO_TIMEOUT_S = 0.5
#: Each CiA 402 state step must show in the statusword within this time (s).
STATE_STEP_TIMEOUT_S = 0.5
#: A fault reset must show (the drive leaves FAULT) within this time (s).
FAULT_RESET_TIMEOUT_S = 0.5
#: A profile-position move must be acknowledged within this time (s).
SETPOINT_ACK_TIMEOUT_S = 0.5
#: Time allowed for a profile-position move to reach its target (s).
MOVE_TIMEOUT_S = 30.0
#: Feedback is missing when no TPDO came for this many SYNCs (and for feedback_timeout_s).
TPDO_MISSES = 3
#: Consecutive TPDOs reporting FAULT without an EMCY before the group latches the fault itself.
FAULT_TPDOS = 2
#: Frames kept for the dump that goes with a fault.
FRAME_RING = 256
#: A frame that cannot be queued for sending within this time is a bus fault (s). slcan writes
#: block on the serial port instead (python-can reconfigures the port when the timeout changes).
SEND_TIMEOUT_S = 0.005
#: Period of the watchdog thread: master heartbeat, heartbeat checks while no cycle runs (s).
WATCHDOG_PERIOD_S = 0.01
#: No cycle for this many SYNC periods: the group is idle and clocks SYNC itself while waiting.
IDLE_PERIODS = 3
#: Points the EPOS2 PVT buffer gets before interpolation is enabled (controlword bit 4).
IP_PREFILL_POINTS = 3
#: On close: time allowed for quick-stopped drives to stop before power goes off (s).
CLOSE_SETTLE_S = 0.3
#: On close: SDO timeout for the best-effort writes (s).
CLOSE_SDO_TIMEOUT_S = 0.1
#: A sequence's wait on the drives' time (the group's watch clock) gives up after this many
#: times its timeout of wall time as well: the drives' time of a caller that does not advance it
#: (:class:`SequenceDeadline`) never leaves a wait hanging.
WALL_BACKSTOP_FACTOR = 30
#: The SYNC frame (COB-ID, data).
_SYNC_FRAME = (SYNC_COB_ID, b"")


@dataclass(frozen=True)
class Feedback:
    """Latest TPDO of one drive: statusword, actual position (counts), its CiA 402 state, when it
    came (s, on the group's clock, ``time.monotonic`` by default) and this drive's fault text
    ('' when none)."""

    node: int
    statusword: int
    position_counts: int
    state: State
    t_s: float
    fault: str = ""


@dataclass(frozen=True)
class GroupFault:
    """The first fault the group latched.

    ``cause`` is machine-readable (``emcy:node2:0x8611``, ``heartbeat:node1``,
    ``no_feedback:node3``, ``no_feedback:all``, ``fault:node2``, ``nmt:node1``,
    ``pdo_length:node1``, ``bus:send``, ``bus:rx``), ``node`` the
    node at fault (0: the bus), ``code`` the EMCY code (0 when none), ``description`` what
    happened, ``at_sync`` the SYNC count when it was seen, ``frames`` the last frames on the bus.
    ``due_at_sync`` is the SYNC count when the fault became a fact: the EMCY's arrival, the
    SYNCs sent before a heartbeat or feedback deadline passed (the group's SYNC count is the
    number of SYNCs sent); the quick stop's delay is ``quick_stop_at_sync - due_at_sync``.
    ``diagnosis`` is what the drive's own records said (0x603F, 0x1003), read after the fault.
    """

    cause: str
    node: int
    code: int
    description: str
    t_s: float
    at_sync: int
    frame_records: tuple[tuple[float, str, int, bytes], ...]
    due_at_sync: int | None = None
    diagnosis: str = ""

    @property
    def frames(self) -> str:
        """The last frames on the bus when the fault was seen: ``t_s dir id [dlc] data``."""
        return format_frames(self.frame_records)

    @property
    def text(self) -> str:
        text = f"node {self.node}: {self.description}" if self.node else self.description
        return f"{text} [{self.diagnosis}]" if self.diagnosis else text

    def error(self) -> RigError:
        """The exception to raise for this fault (DriveFault for a node, CommError for the bus),
        with the frame dump as a note."""
        err: RigError = (
            DriveFault(self.node, self.code, self.description)
            if self.node
            else CommError(self.description)
        )
        if self.diagnosis:
            err.add_note(f"node {self.node}'s own records: {self.diagnosis}")
        err.add_note(f"last CAN frames (t_s dir id [dlc] data):\n{self.frames}")
        return err


def format_frames(frames: Sequence[tuple[float, str, int, bytes]]) -> str:
    """Frame records as text, one per line: ``t_s dir id [dlc] data``."""
    return "\n".join(f"{t:12.6f} {d} {cid:03X} [{len(b)}] {b.hex(' ')}" for t, d, cid, b in frames)


class _Drive:
    """Per-drive bookkeeping (written by the bus listener thread and the caller's thread)."""

    def __init__(self, cfg: DriveConfig, node: canopen.RemoteNode) -> None:
        self.cfg = cfg
        self.id = cfg.node_id
        self.node = node
        self.mode = MODE_BY_NAME[cfg.mode]
        self.layout = epos.pdo_layout(cfg.node_id, self.mode)
        self.controlword = CW_DISABLE_VOLTAGE
        self.feedback = Feedback(cfg.node_id, 0, 0, State.UNKNOWN, float("-inf"))
        self.tpdo_sync = 0
        self.tpdo_count = 0
        self.last_tpdo_s = float("-inf")
        self.fault_tpdos = 0
        self.booted = threading.Event()
        self.present = False
        #: A boot-up message came after configuration: the drive lost its SDO configuration.
        self.rebooted = False
        self.last_emcy: Emcy | None = None
        self.fault_text = ""
        # set-point streams (pp: set/clear of bit 4; ip: PVT points)
        self.last_target: int | None = None
        self.pp_pending = False
        self.ip_points = 0
        self.ip_active = False

    def reset_stream(self) -> None:
        self.last_target, self.pp_pending, self.ip_points, self.ip_active = None, False, 0, False


class SequenceDeadline:
    """The timeout of one wait of a sequence (a 402 step, a fault reset, homing, a move, the
    settle on close): ``timeout_s`` (s) on the drives' time ``drive_clock`` (the group's watch
    clock: the wall clock of real drives, simulated time in lock-step, where it advances one SYNC
    period with each SYNC the waiting group clocks), with a backstop of
    :data:`WALL_BACKSTOP_FACTOR` times ``timeout_s`` on ``wall_clock`` (the group's clock). Where
    the two clocks are one, the backstop never comes first."""

    def __init__(
        self, timeout_s: float, drive_clock: Callable[[], float], wall_clock: Callable[[], float]
    ) -> None:
        self.timeout_s = float(timeout_s)
        self._drive_clock = drive_clock
        self._wall_clock = wall_clock
        self.restart()

    def restart(self) -> None:
        """Count the timeout from now again (a 402 walk: from each step the drives took)."""
        self._drive_t0 = self._drive_clock()
        self._wall_t0 = self._wall_clock()

    def left_s(self) -> float:
        """Time left on the drives' clock (s, >= 0)."""
        return max(0.0, self._drive_t0 + self.timeout_s - self._drive_clock())

    def expired(self) -> str | None:
        """None while time is left; else why: '' when the drives' time passed the timeout, the
        backstop's text (naming itself and both clocks' elapsed times) when wall time did."""
        if self._drive_clock() - self._drive_t0 > self.timeout_s:
            return ""
        wall = self._wall_clock() - self._wall_t0
        if wall > WALL_BACKSTOP_FACTOR * self.timeout_s:
            return (
                f" (wall-clock backstop: {wall:.1f} s of wall time passed, "
                f"{WALL_BACKSTOP_FACTOR} x the timeout, while the drives' clock advanced "
                f"{self._drive_clock() - self._drive_t0:.3f} s)"
            )
        return None


def sdo_controlword_request(controlword: int) -> bytes:
    """An expedited SDO download of 0x6040:00 (2 bytes): the controlword without PDOs."""
    return bytes((0x2B,)) + struct.pack("<HBH", epos.CONTROLWORD, 0, controlword) + bytes(2)
