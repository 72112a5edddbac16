"""A simulated maxon EPOS4/EPOS2 on canopen's LocalNode.

canopen gives the SDO server, the NMT slave, the heartbeat producer and the EMCY producer. This
module adds what LocalNode lacks, as a real drive does it:

- RPDOs applied through their mapping (synchronous ones at the next SYNC, event-driven ones on
  receipt), TPDOs sent through theirs (on every n-th SYNC, or on change), mapping changes refused
  with the CiA 301 abort codes while a PDO is valid;
- the CiA 402 state machine (controlword -> statusword), quick stop with option code 0x605A,
  halt, fault reset on the rising edge of bit 7;
- modes: cyclic synchronous position (EPOS4; targets interpolated over the SYNC period), profile
  position (trapezoidal moves, set-point handshake on bits 4/12, change immediately), homing
  (37/35 actual position; -1..-4 current threshold against a hard stop), interpolated position
  with the PVT buffer 0x20C1 (EPOS2), position mode 0x2062 (EPOS2);
- supervision: following error (0x6065 window for 0x6066 ms), software position limits,
  limit switches, the heartbeat consumer of the master (0x1016; the drive faults with EMCY 0x8130
  when the master goes silent), EMCY on every fault and an error reset EMCY on fault reset;
- a motor with encoder and gearbox under a position loop (:mod:`.plant`).

Time: on every SYNC the axis advances by one SYNC period (``advance_on_sync``, default):
:attr:`SimEpos.sync_period_s` when its owner set it, else the interpolation period 0x60C2; so a
run is reproducible frame for frame. :meth:`SimEpos.step` advances explicitly.

Lag, as on the real drive: the drive samples its actual position at the SYNC and applies the
set-point that came with it after; so the TPDO sent after SYNC k shows the motor as it was when
SYNC k came, before the target of SYNC k acted: one cycle of feedback lag
(:attr:`SimEpos.lag_cycles`, default 1; n > 1 holds each sample back n - 1 further SYNCs; 0 is
the old zero-lag drive whose TPDO already shows the target of its own SYNC).

Refusals, as on the real drive: every SDO or PDO write is checked against the project's limits
table of the family (:mod:`cdcr_ctl.drives.limits`, written from maxon's device descriptions):
a missing object, a read-only one, a wrong length or a value out of range is answered with the
abort code the drive gives.

Coupling a plant (the simulated rig): read :attr:`SimEpos.position_counts` (the actual position
the drive reports), set :attr:`SimEpos.load_torque_Nm` (torque at the gearbox output, + in the
+ count direction) or install :attr:`SimEpos.load_fn` ``(position_counts, velocity_counts_s) ->
torque N·m`` evaluated every integration sub-step; :meth:`SimEpos.displace` shifts the motor.

Fault injection: :meth:`inject_fault` (any EMCY code; :meth:`inject_following_error` 0x8611,
:meth:`inject_over_current` 0x2310), :attr:`emcy_enabled` (False: EMCY frames get lost),
:meth:`stop_heartbeat` / :meth:`start_heartbeat`,
:meth:`go_silent` (stops answering anything: bus off, unplugged) / :meth:`recover` (comes back
with EMCY 0x81FD), :meth:`enter_bus_off` / :meth:`recover_from_bus_off` (an EPOS going bus off
faults itself), :meth:`force_state` (a drive left enabled by a previous session).
Measurements for fault tests: :attr:`transitions` (every state change with its time and SYNC
count) and :attr:`last_target_change` (when the CSP target last changed).

Parts (this class is the facade; the others are its mixins, the state lives on it):
:mod:`.objects` (object dictionary), :mod:`.pdos` (PDO service, SYNC, NMT and SDO gates),
:mod:`.statemachine` (CiA 402, fault reaction), :mod:`.stepping` (axis, supervision,
master heartbeat), :mod:`.plant` (motor, profiles, PVT buffer), :mod:`.od` (the dictionary).
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable

import canopen

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import State
from cdcr_ctl.drives.emcy import BUS_OFF, FOLLOWING_ERROR, OVER_CURRENT
from cdcr_ctl.drives.limits import shipped_table

# Public names of the module before the split (reachable here as before):
from cdcr_ctl.sim.epos.objects import ABORT_MAPPING_LENGTH as ABORT_MAPPING_LENGTH
from cdcr_ctl.sim.epos.objects import ABORT_MAPPING_OBJECT as ABORT_MAPPING_OBJECT
from cdcr_ctl.sim.epos.objects import ABORT_PARAMETER_INCOMPATIBLE as ABORT_PARAMETER_INCOMPATIBLE
from cdcr_ctl.sim.epos.objects import ABORT_VALUE_RANGE as ABORT_VALUE_RANGE
from cdcr_ctl.sim.epos.objects import AT_REST_COUNTS_S as AT_REST_COUNTS_S
from cdcr_ctl.sim.epos.objects import _Objects
from cdcr_ctl.sim.epos.od import IP_BUFFER_SIZE, build_od
from cdcr_ctl.sim.epos.pdos import _Pdo, _PdoService
from cdcr_ctl.sim.epos.plant import Motor, MotorParams, Profile, PvtBuffer
from cdcr_ctl.sim.epos.statemachine import QUICK_STOP_OPTION_ABSENT as QUICK_STOP_OPTION_ABSENT
from cdcr_ctl.sim.epos.statemachine import _StateMachine
from cdcr_ctl.sim.epos.stepping import HOMING_CURRENT_DWELL_S as HOMING_CURRENT_DWELL_S
from cdcr_ctl.sim.epos.stepping import _Stepping

#: SYNCs between the position sample and its TPDO plus one (see the module docstring).
DEFAULT_LAG_CYCLES = 1

#: State changes each simulated drive keeps for the fault-matrix measurements.
TRANSITIONS_KEPT = 256


class SimEpos(_Objects, _PdoService, _StateMachine, _Stepping):
    """One simulated drive on ``network`` (a canopen Network over any python-can bus). ``clock``:
    the drive's own time (s; the lock-step rig gives its simulated clock)."""

    #: Take the exact fast path of the steady CSP cycle's target RPDO (written without the
    #: generic checks); False: every write through canopen's callbacks and the limits check.
    fast_paths = True

    def __init__(
        self,
        network: canopen.Network,
        node_id: int,
        kind: str = "epos4",
        motor: MotorParams | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.node_id = node_id
        self.kind = kind
        self.network = network
        self.node = canopen.LocalNode(node_id, build_od(node_id, kind))
        network.add_node(self.node)
        # Gate canopen's SDO server and NMT slave so a silent drive answers nothing.
        network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        network.unsubscribe(0, self.node.nmt.on_command)
        network.subscribe(self.node.sdo.rx_cobid, self._on_sdo)
        network.subscribe(0, self._on_nmt)
        network.subscribe(0x080, self._on_sync)
        self.motor = Motor(motor or MotorParams())
        self.cpr = self.motor.p.counts_per_rev
        self._lock = threading.RLock()
        self.last_target: int | None = None
        self.last_target_change: tuple[float, int] = (time.monotonic(), 0)
        self.state = State.SWITCH_ON_DISABLED
        self.mode = 0
        self.controlword = 0
        self.offset = 0.0  # reported position = raw encoder counts + offset
        self.profile = Profile()
        self.pvt = PvtBuffer(IP_BUFFER_SIZE)
        self._csp_from = 0.0  # CSP segment: from this demand to the target over one period
        self._csp_to = 0.0
        self._csp_t = 0.0
        self._step_period_s = 0.0  # 0x60C2 as of the running step() (s)
        self._pp_target: float | None = None
        self._setpoint_ack = False
        self._homing_phase = ""  # "", "search", "backoff", "done", "error"
        self._homing_dwell = 0.0
        self._backoff_to = 0.0
        self._homed = False
        self._ferr_s = 0.0
        self.following_error = False
        self.internal_limit = False
        self.error_code = 0
        self.error_register = 0
        #: External torque at the gearbox output (N·m, + in the + count direction).
        self.load_torque_Nm = 0.0
        #: Optional load: (position counts, velocity counts/s) -> output torque N·m, per sub-step.
        self.load_fn: Callable[[float, float], float] | None = None
        #: Advance the axis by one SYNC period on every SYNC.
        self.advance_on_sync = True
        #: Time between two SYNCs (s) as the owner knows it (a real drive runs on its own clock);
        #: None: the interpolation period 0x60C2.
        self.sync_period_s: float | None = None
        #: Feedback lag in SYNCs (module docstring): 1 as on the real drive.
        self.lag_cycles = DEFAULT_LAG_CYCLES
        self._samples: collections.deque[list[tuple[int, bytes]]] = collections.deque()
        #: The limits the drive enforces on writes (maxon's files, via the shipped table).
        self.limits = shipped_table(kind)
        self.silent = False
        self._rebooting = False
        #: Fault hook: False drops EMCY frames (the master must notice the FAULT statusword).
        self.emcy_enabled = True
        # statistics (tests and benchmarks read these)
        self.sync_count = 0
        self.sync_times_s: collections.deque[float] = collections.deque(maxlen=200_000)
        self.rpdo_count = 0
        self.missed_setpoints = 0
        self.max_following_error_counts = 0.0
        self.emcy_sent: list[int] = []
        self._setpoint_since_sync = False
        self._master_hb_cob: int | None = None
        self._master_hb_s: float | None = None
        self._consumer_ms = 0
        #: The drive's own time (s): SYNC arrivals, the master heartbeat's consumer. The
        #: lock-step rig gives its simulated clock.
        self._now: Callable[[], float] = clock
        self._params: dict[tuple[int, int], int] = {}
        #: Values derived from parameters (interpolation period, position limits): emptied with
        #: every write of the objects they come from (``objects._DERIVED_FROM``) and every reset.
        self._derived: dict[str, object] = {}
        self._rpdos: dict[int, _Pdo] = {}
        self._tpdos: list[_Pdo] = []
        self._event_tpdos: list[_Pdo] = []
        self._pdo_dirty = True
        self.node.add_write_callback(self._on_write)
        self.node.add_read_callback(self._on_read)
        self._rebuild_pdos()

    # ================================================================== fault-matrix records
    @property
    def state(self) -> State:
        """CiA 402 state; every change is recorded in :attr:`transitions`."""
        return self._state

    @state.setter
    def state(self, new: State) -> None:
        old = self.__dict__.get("_state")
        self._state = new
        if new is not old:
            # (monotonic time s, SYNCs seen, new state): how fast a fault made the drive safe.
            self.__dict__.setdefault("transitions", collections.deque(maxlen=TRANSITIONS_KEPT))
            self.transitions.append((time.monotonic(), self.__dict__.get("sync_count", 0), new))

    def _record_target(self, target: int) -> None:
        """Remember when the CSP target last changed (time s, SYNCs): a halted master holds it."""
        if target != self.last_target:
            self.last_target = target
            self.last_target_change = (time.monotonic(), self.sync_count)

    # ================================================================== hooks
    def inject_fault(self, code: int) -> None:
        """Fault hook: the drive faults with EMCY ``code`` (power stage off)."""
        self._fault(code)

    inject_emcy = inject_fault

    def inject_following_error(self) -> None:
        self._fault(FOLLOWING_ERROR)

    def inject_over_current(self) -> None:
        self._fault(OVER_CURRENT)

    def stop_heartbeat(self) -> None:
        """Fault hook: stop producing heartbeats (everything else keeps working)."""
        self.node.nmt.stop_heartbeat()

    def start_heartbeat(self) -> None:
        self.node.nmt.start_heartbeat(self._value(epos.HEARTBEAT_PRODUCER))

    def go_silent(self) -> None:
        """Fault hook: answer nothing at all (bus off, cable unplugged): no SDO, PDO, EMCY,
        heartbeat; incoming frames are ignored, the motor keeps its last state."""
        self.silent = True
        self.node.nmt.stop_heartbeat()

    bus_off = go_silent

    def enter_bus_off(self) -> None:
        """Fault hook: the drive's CAN controller goes bus off. As an EPOS does, the drive
        faults (power stage off, error 0x81FD recorded; the EMCY cannot get out) and answers
        nothing until :meth:`recover`, which resumes its heartbeat and reports the fault."""
        self.go_silent()
        self._fault(BUS_OFF)

    def recover_from_bus_off(self) -> None:
        """Back on the bus after :meth:`enter_bus_off`: heartbeats resume, EMCY 0x81FD goes out
        (the drive stays in FAULT until a fault reset). Its CAN controller restarted: the
        master's heartbeat is consumed again from the next one received (CiA 301: monitoring
        starts with the first heartbeat), not timed from the last one before the bus off."""
        self._master_hb_s = None
        self.silent = False
        self.start_heartbeat()
        self._emcy(BUS_OFF)

    def recover(self) -> None:
        """Back on the bus after a bus off: fault with EMCY 0x81FD, heartbeats resume."""
        self.silent = False
        self.start_heartbeat()
        self._fault(BUS_OFF)

    def force_state(self, state: State, mode: int | None = None) -> None:
        """Test hook: put the drive in ``state`` (e.g. left OPERATION ENABLED by a previous
        session), holding its present position."""
        with self._lock:
            if mode is not None:
                self.mode = mode
            self.state = state
            self._hold_here()

    def displace(self, counts: float) -> None:
        """Shift the motor by ``counts`` (slip, a knock); the position loop sees it as an error."""
        with self._lock:
            self.motor.x += counts
