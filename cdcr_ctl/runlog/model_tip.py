"""``/tip/model`` messages (:mod:`cdcr_ctl.runlog.streams`): the model's tip of a row's commanded
pose and its distance to the tracked tip. Apart from :mod:`~cdcr_ctl.runlog.streams` because it
needs numpy: the run-log writer process imports it only with a model to call (the MCAP sink's
``model_tip``, a :class:`ModelTip`), never to start.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from cdcr_ctl.runlog.columns import TIME, TIP_COLUMNS, phi_cmd, theta_cmd
from cdcr_ctl.runlog.streams import TipFromPsi, _clean


def model_tip_message(
    d: Mapping[str, Any], cycle: int, S: int, tip_from_psi: TipFromPsi
) -> dict[str, Any] | None:
    """``/tip/model`` of one row: ``tip_from_psi`` (commanded (θ, φ) per segment, shape (S, 2),
    rad -> tip in the base frame, shape (3,), mm) and the distance to the tracked tip (mm).
    None when the command is incomplete or the model fails."""
    try:
        psi = np.array([[float(d[theta_cmd(i)]), float(d[phi_cmd(i)])] for i in range(1, S + 1)])
        if not np.isfinite(psi).all():
            return None
        tip = np.asarray(tip_from_psi(psi), dtype=float).reshape(3)
    except Exception:  # a pose the model cannot place: no model tip this cycle
        return None
    tracked = np.array([_clean(d.get(c)) for c in TIP_COLUMNS], dtype=float)  # None -> NaN
    err = float(np.linalg.norm(tracked - tip)) if np.isfinite(tracked).all() else None
    x, y, z = (float(v) for v in tip)
    return {"t_s": _clean(d.get(TIME)), "cycle": cycle, "x_mm": x, "y_mm": y, "z_mm": z,
            "error_mm": err}  # fmt: skip


@dataclass(frozen=True)
class ModelTip:
    """The ``/tip/model`` message of a row (:func:`model_tip_message`) with ``tip_from_psi``:
    called as ``model_tip(d, cycle, S)``. Pickles when ``tip_from_psi`` does (the run-log writer
    process gets it inside the MCAP sink's factory)."""

    tip_from_psi: TipFromPsi

    def __call__(self, d: Mapping[str, Any], cycle: int, S: int) -> dict[str, Any] | None:
        return model_tip_message(d, cycle, S, self.tip_from_psi)
