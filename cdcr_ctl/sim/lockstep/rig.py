"""The lock-step simulated rig: the world and the controller's I/O in one process, on one
simulated clock, as fast as the CPU allows and the same on every run.

What is real: the controller's protocol code. Its :class:`~cdcr_ctl.drives.group.DriveGroup`
talks CANopen (SDO set-up, RPDO set-points, SYNC, TPDO feedback, heartbeats) to the simulated EPOS
nodes (:class:`~cdcr_ctl.sim.epos.node.SimEpos`) over :mod:`.canlink`; its Modbus RTU reader
polls the simulated transmitters and its NatNet parser reads the simulated tracker's datagrams
(:mod:`.sensors`). What is simulated: time (:class:`~.clock.SimClock`, one SYNC period per loop
cycle) and the scheduling: each cycle's SYNC steps the nodes by one period inside the loop's send;
then, before the next cycle, :meth:`LockstepRig.advance` steps the truth at its physics rate (by
default in a worker process, one period behind the drives: :mod:`.truthproc`), runs the
load-cell transactions whose replies arrive in that period and delivers the tracker frames due
in it. Every rate and latency is in simulated time; the random streams are seeded
(``seed`` of the simulator YAML), so one seed, one world and one command sequence give the same
logs byte for byte whatever the machine load.

Set-up (boot, SDO configuration) waits on the wall clock, with the simulated world standing
still. The drive sequences (enable, fault reset, the settle on close) clock their own SYNCs while
the loop idles, with the world standing still too: how many such SYNCs a sequence sends depends
on how fast the host answers, so moving the world on them would make the logs depend on the
machine's load. Their timeouts are measured on simulated time (the group's ``watch_clock``),
which stands still meanwhile, so a starved host (a loaded machine, a starved truth worker)
delays an enable but does not fail it; a drive that never answers ends on the wall-clock
backstop, :data:`~cdcr_ctl.drives.group.common.WALL_BACKSTOP_FACTOR` times the timeout.
The attitude sensors (vertebra arm) and the network joystick (a ``joystick`` session's stick
script) run on the simulated clock (:mod:`.attitude`, :mod:`.joystick`; the daemon's joystick
opener is :meth:`LockstepRig.open_joystick`).

Build with :meth:`LockstepRig.open`; hand :attr:`clock`, :attr:`drives`, :attr:`tensions` and
:attr:`tip` to the loop (the daemon's ``RigIO``); set :attr:`SimClock.busy` to the loop's
``busy``; :meth:`close` at the end.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.control.io import (
    AttitudeAngles,
    DriveGroupPort,
    LoadCellTension,
    TrackerTip,
    cell_order,
)
from cdcr_ctl.control.ports import NoTension, NoTip
from cdcr_ctl.drives.group import DriveGroup
from cdcr_ctl.errors import ConfigError
from cdcr_ctl.sensors.loadcell import Calibration
from cdcr_ctl.sensors.loadcell_modbus import ModbusLoadCellBus, spec_silence_s
from cdcr_ctl.sensors.loadcell_sampler import LoadCellSampler
from cdcr_ctl.sensors.natnet import pack_server_info
from cdcr_ctl.sensors.tracker import NatNetTracker, TrackerTransform
from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.epos.node import SimEpos
from cdcr_ctl.sim.epos.plant import MotorParams
from cdcr_ctl.sim.loadcells import ModbusLoadCellSim, SensorNoise
from cdcr_ctl.sim.lockstep.attitude import AttitudeSchedule, open_lockstep_attitude
from cdcr_ctl.sim.lockstep.canlink import CanLink, no_cpu_clock
from cdcr_ctl.sim.lockstep.clock import SimClock
from cdcr_ctl.sim.lockstep.joystick import JoystickSchedule
from cdcr_ctl.sim.lockstep.placement import Placement
from cdcr_ctl.sim.lockstep.sensors import LoadCellSchedule, SerialLoopback, TrackerSchedule
from cdcr_ctl.sim.lockstep.truthproc import LOCKSTEP_SPIN_S, TruthProcess
from cdcr_ctl.sim.simconfig import LoadedSim
from cdcr_ctl.sim.tracker import SimNatNetServer, true_transform

log = logging.getLogger(__name__)

#: Heartbeats (CANopen's liveness checks) between the drive layer and the nodes live on simulated
#: time here: the nodes produce theirs as simulated time passes (:meth:`.canlink.CanLink.tick`),
#: the master's goes out every period it is due (:meth:`DriveGroup.produce_heartbeat`), and both
#: consumers read the simulated clock (the group's ``watch_clock``, the nodes' clock). A host
#: that stalls (a loaded machine, a starved thread) while simulated time stands still trips
#: nothing; a heartbeat missing in simulated time still does. Their periods are these (ms): the
#: set-up, with the world standing still, waits on the wall clock for each node's OPERATIONAL
#: report through the bus listener for three producer periods, and a longer period gives a
#: loaded machine's listener thread more room there.
LOCKSTEP_HEARTBEAT_MS = 1000
LOCKSTEP_HEARTBEAT_CONSUMER_MS = 5000
#: The drive group's watchdog thread (master heartbeat, idle heartbeat checks) wakes this often
#: (s) instead of every 10 ms: on simulated time the loop's advance does its work, and every
#: wake takes the interpreter lock from the loop thread (a thread switch each way).
LOCKSTEP_WATCHDOG_S = 0.1

#: Sensor traffic simulated before the loop's first cycle (s), see :meth:`LockstepRig._prime`.
PRIME_S = 0.1


class LockstepRig:
    """The simulated world of ``loaded`` and the I/O of the controller config ``ctl`` (which may
    differ from the simulator's rig in its robot parameters, never in its devices)."""

    def __init__(
        self,
        loaded: LoadedSim,
        ctl: RigConfig,
        ctl_file: str = "",
        truth_process: bool = True,
        placement: Placement | None = None,
    ) -> None:
        rig = loaded.rig
        if ctl.sensors.attitude is not None and rig.sensors.attitude is None:
            raise ConfigError(
                ctl_file, "sensors.attitude", "the simulated rig has no attitude sensors"
            )
        if ctl.sensors.tracker is not None and ctl.sensors.tracker.kind != "natnet":
            raise ConfigError(
                ctl_file,
                "sensors.tracker.kind",
                "lock-step simulates NatNet only",
                ctl.sensors.tracker.kind,
            )
        if ctl.sensors.load_cells is not None and ctl.sensors.load_cells.protocol != "modbus_rtu":
            raise ConfigError(
                ctl_file,
                "sensors.load_cells.protocol",
                "lock-step simulates Modbus RTU only",
                ctl.sensors.load_cells.protocol,
            )
        self.loaded = loaded
        self.ctl = ctl
        self.ctl_file = ctl_file
        self.clock = SimClock(1.0 / ctl.control.rate_hz, advance=self.advance, t0_s=PRIME_S)
        #: Where the loop thread and the truth worker run (:mod:`.placement`; default: the
        #: first two CPUs this process may use).
        self.placement = Placement.rotated(0) if placement is None else placement
        self.clock.thread_setup = self.placement.pin_this_thread
        self.truth = make_truth(loaded)
        self.physics_period_s = 1.0 / loaded.sim.physics_rate_hz
        self._physics_next_s = 0.0
        self.truth_cpu_s = 0.0
        self.cpu_clock: Callable[[], float] = no_cpu_clock  # see measure_cpu
        self.truth_steps = 0
        self._solved_counts: list[int] = []
        #: The truth solved in a worker process one period behind (:mod:`.truthproc`), or None:
        #: solved here, right after the SYNC.
        self.truth_proc: TruthProcess | None = None
        self._truth_process = truth_process
        self._closers: list[Any] = []
        if truth_process and threading.active_count() == 1 and os.name == "posix":
            # Forked now, while this process has no other thread (as the real-time simulator's
            # worker, cdcr_ctl.sim.rig): the worker starts with this process's imports instead
            # of a spawned interpreter that makes them again before the first solve (on the
            # 2-core VM, `cdcr-ctl demo --design ujoint --quick --lockstep` 16.3-16.9 s ->
            # 15.1-15.2 s). Its first solve comes in _prime, as a spawned one's does.
            self.truth_proc = TruthProcess(
                str(loaded.path), self.truth, "fork", spin_s=LOCKSTEP_SPIN_S
            )
            self._closers.append(self.truth_proc.close)
        self.can = CanLink()
        self.can.clock = self.clock.now
        by_cable = {d.cable: d for d in rig.drives}
        self.nodes = [
            SimEpos(
                self.can.network,
                d.node_id,
                d.type,
                MotorParams(counts_per_rev=d.encoder_counts_per_rev),
                clock=self.clock.now,
            )
            for d in (by_cable[c.name] for c in rig.robot.cables)
        ]
        self.loadcells: LoadCellSchedule | None = None
        self.tracker: TrackerSchedule | None = None
        self.attitude_schedule: AttitudeSchedule | None = None
        self.drives: DriveGroupPort | None = None
        #: The controller's drive group (its master heartbeat goes out from :meth:`advance`).
        self.group: DriveGroup | None = None
        self.tensions: Any = NoTension(len(ctl.robot.cables))
        self.tip: Any = NoTip()
        #: The controller's attitude port (vertebra arm), or None.
        self.attitude: AttitudeAngles | None = None
        #: The simulated network joystick (vertebra arm), or None.
        self.joystick: JoystickSchedule | None = None

    @classmethod
    def open(
        cls, loaded: LoadedSim, ctl: RigConfig, ctl_file: str = "", **options: Any
    ) -> LockstepRig:
        """Build the world, boot the nodes, open and configure the controller's drives and
        sensors (nothing is enabled); closed again if any step fails. ``options``: the
        constructor's ``truth_process`` (solve the truth in a worker process, one period
        behind: :mod:`.truthproc`) and ``placement`` (the CPUs of the loop thread and that
        worker: :mod:`.placement`)."""
        rig = cls(loaded, ctl, ctl_file, **options)
        try:
            rig._open(ctl_file)
        except BaseException:
            rig.close()
            raise
        return rig

    def _open(self, ctl_file: str) -> None:
        ctl, sim = self.ctl, self.loaded.sim
        for n in self.nodes:
            n.boot()
        self._closers.append(self._stop_nodes)
        ctl = relaxed_heartbeats(ctl)
        by_cable = {d.cable: d for d in ctl.drives}
        group = DriveGroup(
            self.can.host,
            ctl.can,
            [by_cable[c.name] for c in ctl.robot.cables],
            watch_clock=self.clock.now,
            file=ctl_file,
        )
        group.watchdog_period_s = LOCKSTEP_WATCHDOG_S
        self.group = group
        self.drives = DriveGroupPort(group)
        self._closers.insert(0, self.drives.close)
        group.boot()
        group.configure()
        names = [c.name for c in ctl.robot.cables]
        lc = ctl.sensors.load_cells
        if lc is not None:
            assert self.loaded.rig.sensors.load_cells is not None
            world_lc = self.loaded.rig.sensors.load_cells
            noise = sim.noise
            device = ModbusLoadCellSim(
                self.truth.cell_tensions,
                [c.slave for c in world_lc.cells],
                world_lc.register_map,
                baudrate=world_lc.serial.baudrate,
                emulate_baud=False,
                noise=SensorNoise(
                    noise.load_cell_N,
                    noise.load_cell_drift_N_per_s,
                    noise.load_cell_dropout,
                    sim.seed,
                ),
                clock=self.clock.now,
            )
            self._closers.append(device.stop)
            s = lc.serial
            port = SerialLoopback(
                device,
                self.clock.now,
                port=s.port,
                baudrate=s.baudrate,
                parity=s.parity,
                stopbits=s.stopbits,
            )
            # The bus silence is kept in simulated time by the schedule, not slept by the link.
            link = ModbusLoadCellBus(
                port,
                [c.slave for c in lc.cells],
                lc.register_map,
                response_timeout_s=s.timeout_s,
                inter_frame_s=0.0,
                port_name=s.port,
            )
            sampler = LoadCellSampler(
                link,
                [Calibration(zero_N=c.zero_N, span=c.span) for c in lc.cells],
                stale_after_s=lc.stale_after_s,
                clock=self.clock.now,
            )
            silence = (
                spec_silence_s(s.baudrate, s.parity, s.stopbits)
                if lc.inter_frame_s is None
                else lc.inter_frame_s
            )
            self.loadcells = LoadCellSchedule(sampler, link, silence)
            self.tensions = LoadCellTension(sampler, cell_order(lc, names, ctl_file))
            self._closers.append(sampler.close)
        tr = ctl.sensors.tracker
        if tr is not None:
            world_tr = self.loaded.rig.sensors.tracker
            assert world_tr is not None
            server = SimNatNetServer(
                self.truth.tip_pose,
                transform=true_transform(world_tr, sim.effects.tracker_offset),
                truth_frame="base",
                rigid_body_id=world_tr.rigid_body_id,
                host="127.0.0.1",
                rate_hz=sim.tracker.rate_hz,
                latency_s=sim.tracker.latency_s,
                noise_mm=sim.noise.tracker_mm,
                dropout=sim.tracker.dropout,
                seed=sim.seed,
            )
            self._closers.append(server.close)
            server._t0 = 0.0  # frame timestamps on simulated time
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            reader = NatNetTracker(
                sock,
                server.command_address,
                TrackerTransform.from_config(tr),
                tr.rigid_body_id,
                stale_after_s=tr.stale_after_s,
                lost_after_s=tr.lost_after_s,
                clock=self.clock.now,
            )
            self._closers.append(reader.close)
            reader.handle_datagram(
                pack_server_info(server.server_info()), server.command_address, 0.0
            )
            self.tracker = TrackerSchedule(server, reader)
            self.tip = TrackerTip(reader)
        att = ctl.sensors.attitude
        if att is not None:
            orientation = getattr(self.truth, "sensor_orientation", None)
            if orientation is None:
                raise ConfigError(
                    ctl_file, "sensors.attitude", f"design {ctl.design} has no joint attitudes"
                )
            self.attitude_schedule, self.attitude = open_lockstep_attitude(
                att, orientation, sim.attitude, sim.seed, self.clock.now
            )
            self._closers.append(self.attitude.close)
        if ctl.sensors.joystick is not None and self.loaded.rig.sensors.joystick is not None:
            self.joystick = JoystickSchedule(self.loaded, self.clock.now)
            self._closers.append(self.joystick.close)
        self._prime()

    def _prime(self) -> None:
        """The world before the loop's first cycle (at ``PRIME_S``): the truth at the drives'
        positions and :data:`PRIME_S` of sensor traffic, so that cycle has fresh samples (a
        real rig's sensors run from the moment they are opened)."""
        self._solved_counts = self.positions()
        self.truth.step(self._solved_counts)
        if self._truth_process:
            if self.truth_proc is None:  # threads were running: spawned
                self.truth_proc = TruthProcess(
                    str(self.loaded.path), self.truth, spin_s=LOCKSTEP_SPIN_S
                )
                self._closers.append(self.truth_proc.close)
            self.placement.pin_worker(self.truth_proc.pid)
            self.truth_proc.submit(self._solved_counts)  # the worker's truth starts alike
            self.truth_proc.collect()
        for sched in (self.loadcells, self.tracker, self.attitude_schedule):
            if sched is not None:
                sched.advance(0.0, PRIME_S)
        self._physics_next_s = PRIME_S + self.physics_period_s

    # ------------------------------------------------------------------ time
    def positions(self) -> list[int]:
        """The nodes' actual positions (counts, cable order)."""
        return [n.position_counts for n in self.nodes]

    def advance(self, t0: float, t1: float) -> None:
        """The world from ``t0`` to ``t1`` (s, simulated): the truth at its physics rate on the
        drives' positions (one solve when a physics tick falls in the period: the positions
        change only at SYNC; none when no drive moved by a count since the last solve), then
        the sensors' transactions and frames of the period."""
        self.can.tick(t1)  # the nodes' heartbeats due by t1
        if self.group is not None:
            self.group.produce_heartbeat(t1)
        proc = self.truth_proc
        if proc is not None and proc.pending:
            proc.collect()  # the positions of the previous period, solved meanwhile
        if self._physics_next_s <= t1:
            c0 = self.cpu_clock()
            counts = self.positions()
            if counts != self._solved_counts:  # a world at rest stays where it is
                if proc is not None:
                    proc.submit(counts)
                else:
                    self.truth.step(counts)
                self._solved_counts = counts
                self.truth_steps += 1
            self.truth_cpu_s += self.cpu_clock() - c0
            while self._physics_next_s <= t1:
                self._physics_next_s += self.physics_period_s
        if self.loadcells is not None:
            self.loadcells.advance(t0, t1)
        if self.tracker is not None:
            self.tracker.advance(t0, t1)
        if self.attitude_schedule is not None:
            self.attitude_schedule.advance(t0, t1)
        if self.joystick is not None:
            self.joystick.advance(t0, t1)

    def measure_cpu(self, on: bool = True) -> None:
        """Count the CPU time of the simulated parts (:meth:`cpu_breakdown_s`) from now on, or
        stop counting. Off by default: it reads the thread-CPU clock (a system call) around every
        frame, poll and solve."""
        clock = time.thread_time if on else no_cpu_clock
        self.cpu_clock = self.can.cpu_clock = clock
        for part in (self.loadcells, self.tracker, self.attitude_schedule):
            if part is not None:
                part.cpu_clock = clock

    def cpu_breakdown_s(self) -> dict[str, float]:
        """CPU time (s) spent so far in the simulated parts: truth (here; ``truth_worker``: in
        the worker process), drives (node handling of the frames, steps at SYNC), TPDO
        decoding, load cells and tracker (both sides)."""
        return {
            "truth": self.truth_cpu_s,
            "truth_worker": self.truth_proc.cpu_s if self.truth_proc else 0.0,
            "sim_drives": self.can.node_time_s,
            "tpdo_decode": self.can.decode_time_s,
            "loadcells_modbus": self.loadcells.cpu_s if self.loadcells else 0.0,
            "tracker_natnet": self.tracker.cpu_s if self.tracker else 0.0,
            "attitude_witmotion": (self.attitude_schedule.cpu_s if self.attitude_schedule else 0.0),
        }

    def open_joystick(self, cfg: Any) -> Any:
        """The daemon's joystick opener: the production network-joystick reader, its stick
        script played on simulated time (:mod:`.joystick`)."""
        if self.joystick is None:
            raise ConfigError(
                self.ctl_file, "sensors.joystick", "the simulated rig has no network joystick"
            )
        if cfg.tcp_address is None:
            raise ConfigError(
                self.ctl_file,
                "sensors.joystick.device",
                "lock-step simulates a network joystick (tcp://HOST:PORT) only",
                cfg.device,
            )
        return self.joystick.open(cfg)

    # ------------------------------------------------------------------ life cycle
    def _stop_nodes(self) -> None:
        for n in self.nodes:
            n.node.nmt.stop_heartbeat()

    def close(self) -> None:
        """Make the drives safe and close everything (every step runs)."""
        self.clock.close()
        for close in self._closers:
            with contextlib.suppress(Exception):
                close()
        self._closers.clear()

    def __enter__(self) -> LockstepRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def relaxed_heartbeats(cfg: RigConfig) -> RigConfig:
    """``cfg`` with the heartbeat periods of :data:`LOCKSTEP_HEARTBEAT_MS` (drives that produce
    or consume none keep 0)."""
    can = cfg.can.model_copy(
        update={"master_heartbeat_ms": LOCKSTEP_HEARTBEAT_MS if cfg.can.master_heartbeat_ms else 0}
    )
    drives = [
        d.model_copy(
            update={
                "heartbeat_producer_ms": LOCKSTEP_HEARTBEAT_MS if d.heartbeat_producer_ms else 0,
                "heartbeat_consumer_ms": (
                    LOCKSTEP_HEARTBEAT_CONSUMER_MS if d.heartbeat_consumer_ms else 0
                ),
            }
        )
        for d in cfg.drives
    ]
    return cfg.model_copy(update={"can": can, "drives": drives})


def tip_true_mm(rig: LockstepRig) -> np.ndarray:
    """The truth's tip (mm, base frame) now (tests)."""
    return np.asarray(rig.truth.tip_pose()[1], dtype=float)


__all__ = ["LockstepRig", "tip_true_mm"]
