"""Adapters from the protocol layers to the loop's ports, and the opening of a rig's I/O.

Here, and only here, robot knowledge meets protocol code: which load cell measures which cable,
which drive pulls which cable. Everything is put in cable order (``robot.cables``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cdcr_ctl.config.loadcells import LoadCellsConfig
from cdcr_ctl.errors import ConfigError
from cdcr_ctl.sensors.loadcell_sampler import LoadCellSampler, forces_and_ages, open_load_cells


class LoadCellTension:
    """:class:`~cdcr_ctl.control.ports.TensionPort` over a :class:`LoadCellSampler`.

    ``order[k]`` is the index of the cell that measures cable ``k`` (-1: no cell on that cable,
    reported as NaN with infinite age).
    """

    def __init__(self, sampler: LoadCellSampler, order: Sequence[int]) -> None:
        self.sampler = sampler
        self._order = np.array(order, dtype=int)
        self._has = self._order >= 0
        self._idx = np.where(self._has, self._order, 0)

    def latest(self) -> tuple[np.ndarray, np.ndarray]:
        force, age = forces_and_ages(self.sampler.latest())
        f = np.where(self._has, force[self._idx], np.nan)
        a = np.where(self._has, age[self._idx], np.inf)
        return f, a

    def close(self) -> None:
        self.sampler.close()


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
    return LoadCellTension(sampler, cell_order(lc, cable_names))
