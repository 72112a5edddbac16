"""The simulated rig: truth physics with simulated EPOS drives, load cells and tracker around it.

What a controller sees is what a real rig offers: CAN frames from EPOS nodes (through an slcan
pseudo-terminal, or a python-can ``virtual`` bus in-process), Modbus RTU replies on a serial
pseudo-terminal, NatNet datagrams on 127.0.0.1. Behind them a physics thread reads the drives'
actual positions, solves the truth model (:mod:`cdcr_ctl.sim.truth`) and publishes tensions and the
tip pose to the sensor simulators.

The connection points are the ones the rig config (``rig:`` of the simulator YAML) names: the slcan
pty and load-cell pty are symlinked to ``can.channel`` and ``sensors.load_cells.serial.port``, the
tracker listens on ``sensors.tracker.host``/``command_port``. So the daemon runs against the
simulator with the rig config unchanged. A ``can.channel`` or load-cell ``serial.port`` of
``socket://127.0.0.1:PORT`` puts the slcan adapter or the transmitters on that loopback TCP port
instead of a pty (a networked adapter, a serial-to-Ethernet converter; the bytes reach the daemon
in the simulator's own system call, not through the kernel's tty worker thread, which a loaded
machine delays: :mod:`cdcr_ctl.sim.slcan_device`).

The truth is the rig's design's (:func:`cdcr_ctl.sim.design_truth.make_truth`): constant-curvature
disks, universal-joint segments or vertebrae. A rig with ``sensors.attitude`` (the vertebra arm)
gets one simulated WitMotion sensor per joint end on a pty (symlinked to its configured port),
reading the truth's joint-end orientation. A rig whose ``sensors.joystick.device`` is
``tcp://127.0.0.1:PORT`` gets a simulated network joystick there
(:class:`cdcr_ctl.sim.joystick.NetworkJoystickServer`) that plays the simulator config's stick
script (``joystick:``; the paper's Fig. 12 session by default) to each client that connects.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cdcr_ctl.ownership import Ownership
from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.loadcells import SensorNoise, sim_for_config
from cdcr_ctl.sim.lockstep.truthproc import TruthProcess
from cdcr_ctl.sim.simconfig import LoadedSim, sim_owned_keys
from cdcr_ctl.sim.tracker import sim_tracker_from_config

log = logging.getLogger(__name__)


@dataclass
class SimCounters:
    physics_steps: int = 0
    physics_overruns: int = 0
    physics_max_ms: float = 0.0
    solve_failures: int = 0
    faults_injected: list[str] = field(default_factory=list)


class SimRig:
    """Builds and runs every simulated device for one simulator config.

    ``can_interface``: ``"slcan"`` puts the EPOS nodes behind an slcan pty (other processes connect
    with python-can's slcan interface), ``"virtual"`` puts them on a python-can virtual bus of
    channel ``can_channel`` in this process (tests).
    """

    def __init__(
        self,
        loaded: LoadedSim,
        can_interface: str = "slcan",
        can_channel: str | None = None,
        link_paths: bool = True,
        truth_worker: bool = False,
        owner: Ownership | None = None,
    ) -> None:
        self.loaded = loaded
        self.rig = loaded.rig
        self.truth = make_truth(loaded)
        self.counters = SimCounters()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.can_interface = can_interface
        self.can_channel = can_channel or self.rig.can.channel
        self.link_paths = link_paths
        self.drives: Any = None
        self.load_cells: Any = None
        self.tracker: Any = None
        self.attitude: list[Any] = []
        self.joystick: Any = None
        self._links: list[Path] = []
        #: The locks of :meth:`owned_keys` (a caller that took them first may pass its own).
        self._owner = owner or Ownership()
        #: Solve the truth in a worker process (``cdcr-ctl sim``), see :meth:`_physics`.
        self.truth_worker = truth_worker
        self._truth_proc: TruthProcess | None = None

    # ------------------------------------------------------------------ lifecycle
    def owned_keys(self) -> list[str]:
        """What this simulator stands in for (:func:`~cdcr_ctl.sim.simconfig.sim_owned_keys`)."""
        return sim_owned_keys(self.rig, self.can_interface, self.link_paths)

    def start(self) -> SimRig:
        # First: a second simulator of the same rig refuses here, before it replaces the first
        # one's links or binds its ports (AlreadyOwned names the first one's pid).
        self._owner.take_all(self.owned_keys())
        try:
            return self._start()
        except BaseException:
            self.stop()
            raise

    def _start(self) -> SimRig:
        if self.truth_worker:
            # First, while this process has no other thread: forked then, the worker starts
            # with this process's imports (spawned, ~1.5 s of its own, which every rig start
            # of the system tests paid).
            alone = threading.active_count() == 1
            method = "fork" if alone and os.name == "posix" else "spawn"
            self._truth_proc = TruthProcess(str(self.loaded.path), self.truth, method)
        from cdcr_ctl.sim.epos.rig import SimDriveBus  # the simulated EPOS nodes on their bus

        noise = self.loaded.sim.noise
        js = self.rig.sensors.joystick
        if js is not None and js.tcp_address is not None:
            # First: a taken port fails here, before any other device runs.
            self.joystick = network_joystick(self.loaded).start()
        if self.rig.sensors.load_cells is not None:
            lc = self.rig.sensors.load_cells
            link = lc.serial.port if self.link_paths else None
            if link and not link.startswith("socket://"):
                Path(link).parent.mkdir(parents=True, exist_ok=True)
            self.load_cells = sim_for_config(
                lc,
                self.truth.cell_tensions,
                noise=SensorNoise(
                    noise.load_cell_N,
                    noise.load_cell_drift_N_per_s,
                    noise.load_cell_dropout,
                    self.loaded.sim.seed,
                ),
                link=link,
            )
            self.load_cells.start()
        if self.rig.sensors.tracker is not None:
            self.tracker = sim_tracker_from_config(
                self.truth.tip_pose, self.rig.sensors.tracker, self.loaded.sim
            )
            self.tracker.start()
        if self.rig.sensors.attitude is not None:
            self._start_attitude()
        tcp_port = adapter_tcp_port(self.rig.can.channel) if self.can_interface == "slcan" else None
        self.drives = SimDriveBus(
            self.rig,
            interface=self.can_interface,
            channel=self.can_channel,
            link=self.rig.can.channel
            if (self.link_paths and self.can_interface == "slcan" and tcp_port is None)
            else None,
            tcp=tcp_port is not None,
            tcp_port=tcp_port or 0,
        )
        self.drives.start()
        if self._truth_proc is not None:
            # The worker's first solve, at the drives' present positions: the world is solved
            # from the moment this returns (``cdcr-ctl sim`` then says it is ready).
            self._truth_proc.submit(self.drives.actual_positions())
            self._truth_proc.collect()
        self._thread = threading.Thread(target=self._physics, name="sim-physics", daemon=True)
        self._thread.start()
        return self

    def _start_attitude(self) -> None:
        """One simulated WitMotion per configured sensor (joint order) on the truth."""
        from cdcr_ctl.sim.attitude import SimWitMotion

        cfg = self.rig.sensors.attitude
        assert cfg is not None
        orientation = getattr(self.truth, "sensor_orientation", None)
        if orientation is None:
            raise ValueError(f"design {self.rig.design} has no joint attitudes to simulate")
        sim = self.loaded.sim.attitude
        for i, port in enumerate(cfg.sensors):
            dev = SimWitMotion(
                lambda i=i: orientation(i),
                rate_hz=sim.rate_hz,
                noise_deg=sim.noise_deg,
                yaw_offset_deg=sim.yaw_offset_deg,
                latency_s=sim.latency_s,
                seed=self.loaded.sim.seed + i,
            )
            self.attitude.append(dev)
            if self.link_paths:
                link = Path(port.port)
                link.parent.mkdir(parents=True, exist_ok=True)
                with contextlib.suppress(FileNotFoundError):
                    link.unlink()
                link.symlink_to(dev.path)
                self._links.append(link)
            dev.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self._truth_proc is not None:
            self._truth_proc.close()
        for dev in (self.joystick, self.drives, self.load_cells, self.tracker, *self.attitude):
            if dev is not None:
                with contextlib.suppress(Exception):
                    dev.stop()
        for dev in self.attitude:
            with contextlib.suppress(Exception):
                dev.close()
        for link in self._links:
            with contextlib.suppress(OSError):
                link.unlink()
        self._owner.release()

    def __enter__(self) -> SimRig:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def connection_info(self) -> dict[str, Any]:
        """Where a controller connects (printed by ``cdcr-ctl sim``)."""
        info: dict[str, Any] = {
            "can": {"interface": self.can_interface, "channel": self.drives.channel_path},
            "pid": os.getpid(),
        }
        if self.load_cells is not None:
            serial = self.rig.sensors.load_cells.serial
            info["load_cells"] = {
                "port": str(self.load_cells.path),
                # What the daemon's side of the link must be set to (the rig config's).
                "baudrate": serial.baudrate,
                "parity": serial.parity,
                "stopbits": serial.stopbits,
            }
        if self.attitude:
            info["attitude"] = [str(dev.path) for dev in self.attitude]
        if self.joystick is not None:
            info["joystick"] = {
                "url": self.joystick.url,
                "script": self.loaded.sim.joystick.script,
                "format": "struct input_event, 24-byte records, little endian",
            }
        if self.tracker is not None:
            info["tracker"] = {"kind": self.rig.sensors.tracker.kind, **tracker_ports(self.tracker)}
        return info

    # ------------------------------------------------------------------ physics
    def _physics(self) -> None:
        """The truth at ``physics_rate_hz`` on the drives' positions.

        With ``truth_worker`` the solve runs in a process of its own (:class:`TruthProcess`) and
        this thread waits for it on a semaphore, without the interpreter lock. The truth is the
        simulator's only heavy computation; in this process it held the lock for most of a
        core's worth of small numpy steps and filled the garbage collector's generations, and
        the stand-in devices' threads (the drives' SYNC answers and heartbeats, the load cells,
        the tracker) waited behind it: under load the drives fell silent for 0.2-0.3 s at a time
        (heartbeat lost, no TPDO from any drive) with nothing wrong in the daemon. Real drives
        and sensors have processors of their own.
        """
        period = 1.0 / self.loaded.sim.physics_rate_hz
        next_t = time.monotonic()
        proc = self._truth_proc
        while not self._stop.is_set():
            t0 = time.monotonic()
            counts = self.drives.actual_positions()
            if proc is not None:
                proc.submit(counts)
                proc.collect()
            else:
                self.truth.step(counts)
            self.counters.physics_steps += 1
            self.counters.solve_failures = self.truth.failures
            dt = time.monotonic() - t0
            self.counters.physics_max_ms = max(self.counters.physics_max_ms, dt * 1e3)
            next_t += period
            wait = next_t - time.monotonic()
            if wait < 0:
                self.counters.physics_overruns += 1
                next_t = time.monotonic()
            else:
                self._stop.wait(wait)


def adapter_tcp_port(channel: str) -> int | None:
    """The loopback TCP port of an slcan ``can.channel`` of the form ``socket://127.0.0.1:PORT``
    (the simulated adapter then listens there instead of on a pty: :mod:`.slcan_device` says
    why), or None for a pty path."""
    if not channel.startswith("socket://"):
        return None
    host, _, port = channel.removeprefix("socket://").rpartition(":")
    if host not in ("127.0.0.1", "localhost") or not port.isdigit():
        raise ValueError(
            f"can.channel {channel!r}: the simulated adapter serves socket://127.0.0.1:PORT only"
        )
    return int(port)


def stick_script(loaded: LoadedSim) -> list[Any]:
    """The simulator config's stick session as :class:`~cdcr_ctl.sim.joystick.JoystickFrame`
    keyframes (times from the connection, s): ``paper`` or a YAML script file."""
    from cdcr_ctl.model.vertebra.follow import paper_session
    from cdcr_ctl.sim.joystick import JoystickFrame, load_stick_script

    cfg = loaded.sim.joystick
    js = loaded.rig.sensors.joystick
    assert js is not None
    if cfg.script == "paper":
        frames = [
            JoystickFrame(f.t_s, f.x, f.y, f.buttons)
            for f in paper_session(js.advance_button, scale=cfg.scale)
        ]
    else:
        frames = load_stick_script(loaded.path.parent / cfg.script)
    cut = cfg.disconnect_after_s
    if cut is not None:
        before = [f for f in frames if f.t_s <= cut]
        last = before[-1] if before else JoystickFrame(0.0)
        frames = [*before, JoystickFrame(cut, last.x, last.y, last.buttons)]
    return frames


def network_joystick(loaded: LoadedSim) -> Any:
    """A (not started) :class:`~cdcr_ctl.sim.joystick.NetworkJoystickServer` on the rig's
    ``sensors.joystick.device`` address, playing :func:`stick_script` to each client.

    The frames are the operator's intent; the raw values sent are what the configured stick
    reports (an inverted axis is sent inverted, so the controller's ``invert_*`` undoes it).
    """
    from cdcr_ctl.sensors.joystick import DEFAULT_RANGE, config_axis_range
    from cdcr_ctl.sim.joystick import JoystickFrame, NetworkJoystickServer, ScriptedJoystick

    js = loaded.rig.sensors.joystick
    assert js is not None and js.tcp_address is not None
    host, port = js.tcp_address
    sx = -1.0 if js.invert_x else 1.0
    sy = -1.0 if js.invert_y else 1.0
    frames = [JoystickFrame(f.t_s, sx * f.x, sy * f.y, f.buttons) for f in stick_script(loaded)]
    rng = config_axis_range(js) or DEFAULT_RANGE
    disconnect = loaded.sim.joystick.disconnect_after_s is not None

    def source() -> ScriptedJoystick:
        return ScriptedJoystick(
            frames,
            axis_x=js.axis_x,
            axis_y=js.axis_y,
            axis_range=rng,
            disconnect_at_end=disconnect,
        )

    return NetworkJoystickServer(source, host=host, port=port)


def tracker_ports(server: Any) -> dict[str, Any]:
    """The simulated tracker's bound addresses: a NatNet server's command and data sockets, a
    line stream's one socket (host and port as the kernel reports them)."""
    if hasattr(server, "command_address"):
        host, command_port = server.command_address[:2]
        return {"host": host, "command_port": command_port, "data_port": server.data_address[1]}
    if getattr(server, "target", None) is not None:  # UDP: datagrams sent to the target
        host, port = server.target[:2]
        return {"host": host, "port": port, "source_port": server.address[1]}
    if hasattr(server, "address"):
        host, port = server.address[:2]
        return {"host": host, "port": port}
    return {}
