"""The loop's log row: the column layout of one cycle's flat array (:class:`RowLayout`) and the
immutable row mapping the writer thread turns into columns (:class:`CycleRow`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np

from cdcr_ctl.runlog.columns import lateness_cell_us, t_cell


class RowLayout:
    """The columns of a loop row (run-log names) and, per column, where its value sits in the
    cycle's flat array ``[psi (S x 2), q_nominal, q_cmd, q_act, tension (K each), tip (3)]``."""

    def __init__(self, n_segments: int, n_cables: int) -> None:
        S, K = n_segments, n_cables
        per_cable = ("q_nominal_mm", "q_cmd_mm", "q_act_mm", "tension_N")
        self.keys = (
            [f"seg{i}_{a}_cmd_rad" for i in range(1, S + 1) for a in ("theta", "phi")]
            + [f"cable{k}_{c}" for k in range(1, K + 1) for c in per_cable]
            + ["tip_x_mm", "tip_y_mm", "tip_z_mm"]
        )
        order = list(range(2 * S))
        order += [2 * S + c * K + k for k in range(K) for c in range(len(per_cable))]
        order += [2 * S + len(per_cable) * K + j for j in range(3)]
        self.order = np.array(order, dtype=np.intp)
        flat_keys = [""] * len(order)
        for key, pos in zip(self.keys, order, strict=True):
            flat_keys[pos] = key
        #: Name of each value of the flat array (one tuple, the same object every cycle).
        self.flat_keys = tuple(flat_keys)


class CycleRow(Mapping[str, Any]):
    """One cycle's log row: ``t_s``, ``cycle``, the :class:`RowLayout` columns, ``lateness_us``,
    ``event``. The loop thread only keeps the cycle's numbers (one array); the mapping is made
    on first use, by the run-log writer's thread or a status request, off the loop's path."""

    __slots__ = ("_cycle", "_dict", "_event", "_lateness_s", "_layout", "_t_s", "_values")

    def __init__(
        self,
        layout: RowLayout,
        t_s: float,
        cycle: int,
        values: np.ndarray,
        lateness_s: float,
        event: str,
    ) -> None:
        self._layout, self._t_s, self._cycle = layout, t_s, cycle
        self._values, self._lateness_s, self._event = values, lateness_s, event
        self._dict: dict[str, Any] | None = None

    def columns(self) -> dict[str, Any]:
        """The row as a plain dict (made once)."""
        d = self._dict
        if d is None:
            values = self._values[self._layout.order].tolist()
            d = {"t_s": t_cell(self._t_s), "cycle": self._cycle}
            d.update(zip(self._layout.keys, values, strict=True))
            d["lateness_us"] = lateness_cell_us(self._lateness_s)
            d["event"] = self._event
            self._dict = d
        return d

    def row_parts(self) -> tuple[tuple[str, ...], np.ndarray, float, int, float, str]:
        """(names of ``values``, float64 ``values``, ``t_s``, ``cycle``, lateness (s),
        ``event``): the row for a writer that copies numbers (no dict, no reordering, no
        rounding: the writer rounds ``t_s`` and the lateness with :func:`t_cell` and
        :func:`lateness_cell_us`, as :meth:`columns` does)."""
        return (
            self._layout.flat_keys,
            self._values,
            self._t_s,
            self._cycle,
            self._lateness_s,
            self._event,
        )

    def __getitem__(self, key: str) -> Any:
        return self.columns()[key]

    def get(self, key: str, default: Any = None) -> Any:
        return self.columns().get(key, default)

    def __contains__(self, key: object) -> bool:
        return key in self.columns()

    def __iter__(self) -> Iterator[str]:
        return iter(self.columns())

    def __len__(self) -> int:
        return len(self.columns())

    def __repr__(self) -> str:
        return f"CycleRow({self.columns()!r})"


RowSink = Callable[[Mapping[str, float | str]], None]
