"""Adapters from the protocol layers to the loop's ports, and the opening of a rig's I/O.

Here, and only here, robot knowledge meets protocol code: which load cell measures which cable,
which drive pulls which cable. Everything is put in cable order (``robot.cables``).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cdcr_ctl.config.loadcells import LoadCellsConfig
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.config.tracking import TrackerConfig
from cdcr_ctl.control.ports import DriveState, NoTension, NoTip, RigIO
from cdcr_ctl.drives.busload import check_drives_bus_load
from cdcr_ctl.drives.group import DriveGroup, open_drive_group
from cdcr_ctl.errors import CommError, ConfigError
from cdcr_ctl.sensors.attitude import AttitudeSensors, open_attitude_sensors
from cdcr_ctl.sensors.loadcell_sampler import LoadCellSampler, open_load_cells
from cdcr_ctl.sensors.tracker import open_tracker


class LoadCellTension:
    """:class:`~cdcr_ctl.control.ports.TensionPort` over a :class:`LoadCellSampler`.

    ``order[k]`` is the index of the cell that measures cable ``k`` (-1: no cell on that cable,
    reported as NaN with infinite age).
    """

    def __init__(
        self,
        sampler: LoadCellSampler,
        order: Sequence[int],
        reopen: Callable[[], LoadCellSampler] | None = None,
    ) -> None:
        self.sampler = sampler
        self._reopen = reopen
        self._order = [int(i) for i in order]

    def latest(self) -> tuple[np.ndarray, np.ndarray]:
        f, a = self.latest_lists()
        return np.array(f, dtype=float), np.array(a, dtype=float)

    def latest_lists(self) -> tuple[list[float], list[float]]:
        """:meth:`latest` as lists of floats (the loop's read every cycle: numpy's indexing and
        where() on three values cost more than the values); the sampler's force and age alone,
        not its whole samples."""
        forces, ages = self.sampler.latest_forces()
        f = [float(forces[i]) if i >= 0 else math.nan for i in self._order]
        a = [float(ages[i]) if i >= 0 else math.inf for i in self._order]
        return f, a

    def close(self) -> None:
        self.sampler.close()

    def reopen(self) -> None:
        """Close the serial port and open it again (a transmitter or pty that went away and came
        back); :meth:`latest` reads the new sampler from the next call on."""
        if self._reopen is None:
            raise CommError("this load-cell port cannot re-open")
        with contextlib.suppress(Exception):
            self.sampler.close()
        sampler = self._reopen()
        sampler.start()
        self.sampler = sampler


def cell_order(lc: LoadCellsConfig, cable_names: Sequence[str], file: str = "") -> list[int]:
    """Index of the cell measuring each cable, in cable order (-1 where none does)."""
    by_cable = {cell.cable: i for i, cell in enumerate(lc.cells)}
    for i, cell in enumerate(lc.cells):
        if cell.cable not in cable_names:
            raise ConfigError(
                file, f"sensors.load_cells.cells[{i}].cable", "no such cable", cell.cable
            )
    return [by_cable.get(name, -1) for name in cable_names]


def open_tension(lc: LoadCellsConfig, cable_names: Sequence[str]) -> LoadCellTension:
    """Open the load-cell bus and start sampling (raises SensorError naming the port)."""
    sampler = open_load_cells(lc)
    sampler.start()
    return LoadCellTension(sampler, cell_order(lc, cable_names), lambda: open_load_cells(lc))


class TrackerTip:
    """:class:`~cdcr_ctl.control.ports.TipPort` over a tracker reader (NatNet or line stream)."""

    def __init__(self, tracker: Any, reopen: Callable[[], Any] | None = None) -> None:
        self.tracker = tracker
        self._reopen = reopen

    def latest(self) -> tuple[np.ndarray, float]:
        p, age = self.tracker.position_and_age()
        return np.asarray(p, dtype=float), float(age)

    def close(self) -> None:
        self.tracker.close()

    def reopen(self) -> None:
        """Connect to the tracker again (a tracker server restarted does not know this client);
        :meth:`latest` reads the new reader from the next call on."""
        if self._reopen is None:
            raise CommError("this tracker port cannot re-open")
        with contextlib.suppress(Exception):
            self.tracker.close()
        self.tracker = self._reopen()


class AttitudeAngles:
    """:class:`~cdcr_ctl.control.ports.AttitudePort` over :class:`AttitudeSensors` (joint order).

    A stale sensor (no frame within its ``stale_after_s``, or its port failed) reads as NaN
    angles with its age, so the model falls back to open loop for that joint.
    """

    def __init__(self, sensors: AttitudeSensors) -> None:
        self.sensors = sensors

    def latest(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        samples = self.sensors.latest()
        roll = np.array([math.nan if s.stale else s.roll_rad for s in samples])
        pitch = np.array([math.nan if s.stale else s.pitch_rad for s in samples])
        return roll, pitch, np.array([s.age_s for s in samples])

    def close(self) -> None:
        self.sensors.close()


def open_tip(tracker_cfg: TrackerConfig) -> TrackerTip:
    """Connect to the tracker (raises SensorError naming host and port when it does not answer)."""
    return TrackerTip(open_tracker(tracker_cfg), lambda: open_tracker(tracker_cfg))


class DriveGroupPort:
    """:class:`~cdcr_ctl.control.ports.DrivePort` over a :class:`~cdcr_ctl.drives.group.DriveGroup`
    whose drives are in cable order."""

    def __init__(self, group: DriveGroup, reopen: Callable[[], DriveGroup] | None = None) -> None:
        """``reopen()`` opens the bus and boots the drives again (see :meth:`reopen`)."""
        self.group = group
        self._clock = group.clock
        self._reopen = reopen

    def reopen(self) -> None:
        """Close the bus and open it again, booting and configuring every drive (after the bus
        or the drives were lost: a restarted rig, an adapter unplugged and back). The loop
        must be paused meanwhile. Raises what opening raises; the old group is closed."""
        if self._reopen is None:
            raise CommError("this drive port cannot re-open its bus")
        with contextlib.suppress(Exception):
            self.group.close()
        self.group = self._reopen()
        self._clock = self.group.clock

    def send_cycle(self, targets_counts: Sequence[int]) -> None:
        self.group.send_cycle(targets_counts)

    def feedback(self) -> list[DriveState]:
        now = self._clock()
        fault = self.group.fault()
        # The group's first fault belongs to its node only (node 0, the bus, to none of them:
        # the status shows it as the rig's fault); a drive's own fault text otherwise.
        return [
            DriveState(
                f.position_counts,
                f.state.value,
                f.fault or (fault.text if fault is not None and fault.node == f.node else ""),
                now - f.t_s,
            )
            for f in self.group.feedback()
        ]

    def positions(self) -> list[int]:
        """The drives' positions (counts) of :meth:`feedback`, without its records (the loop's
        read every cycle)."""
        return [f.position_counts for f in self.group.feedback()]

    def first_fault(self) -> tuple[str, str] | None:
        return self.group.first_fault()

    def enable(self) -> None:
        self.group.enable()

    def disable(self) -> None:
        self.group.disable()

    def quick_stop(self) -> None:
        self.group.quick_stop()

    def home(self) -> list[int]:
        return self.group.home(sync=lambda: self.group.send_sync())

    def reset_faults(self) -> list[str]:
        """Reset; the lines say which drives were reconfigured after a reboot."""
        return self.group.reset_faults()

    def log_traffic(self, path: str | Path | None, tap: Any = None) -> None:
        """Raw CAN traffic of the following cycles to ``path`` (python-can ASC) and to ``tap``
        (a python-can listener) if given; None stops."""
        self.group.log_traffic(path, tap)

    def close(self) -> None:
        self.group.close()


def open_drives(cfg: RigConfig, file: str = "") -> DriveGroupPort:
    """Check the bus budget, open the bus, boot and configure every drive (cable order).

    Nothing is enabled here. On any failure the bus is closed again before the error propagates.
    """
    by_cable = {d.cable: d for d in cfg.drives}
    drives = [by_cable[c.name] for c in cfg.robot.cables]
    check_drives_bus_load(
        drives, cfg.can.sync_period_s, cfg.can.bitrate, cfg.can.max_bus_load, file
    )
    group = open_drive_group(cfg.can, drives, file=file)
    return DriveGroupPort(group, reopen=lambda: open_drive_group(cfg.can, drives, file=file))


def open_rig_io(cfg: RigConfig, path: str | Path, traffic_dir: str | Path | None = None) -> RigIO:
    """Open drives, load cells and tracker of ``cfg``; close what was opened if one fails."""

    opened: list[Any] = []
    try:
        drives = open_drives(cfg, str(path))
        opened.append(drives)
        names = [c.name for c in cfg.robot.cables]
        tensions: Any = NoTension(len(names))
        if cfg.sensors.load_cells is not None:
            tensions = open_tension(cfg.sensors.load_cells, names)
            opened.append(tensions)
        tip: Any = NoTip()
        if cfg.sensors.tracker is not None:
            tip = open_tip(cfg.sensors.tracker)
            opened.append(tip)
        attitude: AttitudeAngles | None = None
        if cfg.sensors.attitude is not None:
            attitude = AttitudeAngles(open_attitude_sensors(cfg.sensors.attitude))
            opened.append(attitude)
    except BaseException:
        for dev in reversed(opened):
            with contextlib.suppress(Exception):
                dev.close()
        raise

    def close() -> None:
        for dev in (attitude, tip, tensions, drives):
            if dev is not None:
                with contextlib.suppress(Exception):
                    dev.close()

    return RigIO(drives=drives, tensions=tensions, tip=tip, close=close, attitude=attitude)
