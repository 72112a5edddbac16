"""Transmission effects between the drive and the cable leaving the spool.

Pure physics, numpy only: no I/O, no clocks. Units: mm. These are the
:class:`~cdcr_ctl.model.cc_disk.params.ActuatorEffect` implementations applied by
:class:`~cdcr_ctl.model.cc_disk.forward.ForwardStepper`:

* :class:`BacklashPlay` - a play (dead band) of width b in the transmission,
  y = clip(y_prev, x - b/2, x + b/2) (the "play operator"; Yang et al. 2022 eq. 13-17 model the
  same dead zone at direction reversal).
* :class:`TransmissionScale` - the cable moves ``factor`` mm per mm the drive reports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from cdcr_ctl.model.cc_disk.params import Effects, RobotParams
from cdcr_ctl.model.shared.deadzone import dead_zone_inverse, play_forward


@dataclass(frozen=True)
class BacklashPlay:
    """Play of total width ``width_mm`` (per cable or one for all) between drive and cable.

    Forward (:meth:`to_cable`): the play operator of :mod:`cdcr_ctl.model.shared.deadzone`,
    y_k = clip(y_prev_k, x_k - b_k/2, x_k + b_k/2), starting centred (y = 0 at x = 0). Inverse
    (:meth:`to_actuator`): :func:`~cdcr_ctl.model.shared.deadzone.dead_zone_inverse`, x = y + c with
    the pre-travel c moving towards +-b/2 in the direction of the last motion of the wanted cable
    position (kept while it holds), by at most ``max_step_mm`` per call (inf: the exact inverse);
    the direction turns once the wanted position has come back from its extremum by more than
    ``hysteresis_mm`` (see :func:`~cdcr_ctl.model.shared.deadzone.dead_zone_inverse`).
    State: (K, 4) array of [last cable position (forward) or last wanted cable position
    (inverse), pre-travel c, extremum of the wanted position, direction (inverse only)], mm;
    made by :meth:`new_state` and owned by the caller (the control loop keeps it from cycle to
    cycle). Yang et al. 2022 eq. 13-17.
    """

    width_mm: float | tuple[float, ...]
    max_step_mm: float = math.inf
    hysteresis_mm: float = 0.0
    #: half widths per cable count, made on first use (the loop's path stays in plain floats)
    _halves: dict[int, list[float]] = field(
        default_factory=dict, init=False, repr=False, compare=False, hash=False
    )

    def _b(self, n: int) -> np.ndarray:
        b = np.broadcast_to(np.asarray(self.width_mm, dtype=float), (n,))
        if np.any(b < 0):
            raise ValueError("backlash width must be >= 0")
        return b

    def new_state(self, n_cables: int) -> np.ndarray:
        return np.zeros((n_cables, 4))

    def _half(self, n: int) -> list[float]:
        half = self._halves.get(n)
        if half is None:
            half = self._halves.setdefault(n, (0.5 * self._b(n)).tolist())
        return half

    def to_cable(self, q_act_mm: np.ndarray, state: np.ndarray) -> np.ndarray:
        x = np.asarray(q_act_mm, dtype=float).tolist()
        y = play_forward(x, state[:, 0].tolist(), self._half(len(x)))
        state[:, 0] = y
        return np.array(y)

    def to_actuator(self, q_cable_mm: np.ndarray, state: np.ndarray) -> np.ndarray:
        y = np.asarray(q_cable_mm, dtype=float).tolist()
        half = self._half(len(y))
        rows = state.tolist()
        x = dead_zone_inverse(y, rows, half, self.max_step_mm, self.hysteresis_mm)
        state[:, :] = rows
        return np.array(x)


def with_cable_play(
    params: RobotParams,
    effects: Effects,
    max_step_mm: float = math.inf,
    hysteresis_mm: float = 0.0,
) -> Effects:
    """``effects`` with the cables' own lost motion (``CableParams.backlash_mm``) as the first
    (drive-side) transmission effect, :class:`BacklashPlay` with per-cable widths (mm).

    Unchanged when every cable has zero play or ``effects.actuator`` already holds a play (a
    discrepancy candidate that brings its own). ``max_step_mm``: the inverse's pre-travel step
    bound per call, ``hysteresis_mm`` its reversal threshold (see
    :mod:`cdcr_ctl.model.shared.deadzone`).
    """
    widths = tuple(c.backlash_mm for c in params.cables)
    if not any(w > 0 for w in widths) or any(isinstance(e, BacklashPlay) for e in effects.actuator):
        return effects
    play = BacklashPlay(widths, max_step_mm, hysteresis_mm)
    return replace(effects, actuator=(play, *effects.actuator))


@dataclass(frozen=True)
class TransmissionScale:
    """Cable travel per reported drive travel (dimensionless, per cable or one for all).

    A counts-per-mm (or screw lead) error: the drive reports x mm, the cable moves factor * x.
    The truth's ``counts_per_mm_scale`` s gives factor = 1/s. Stateless.
    """

    factor: float | tuple[float, ...]

    def new_state(self, n_cables: int) -> None:
        return None

    def to_cable(self, q_act_mm: np.ndarray, state: None) -> np.ndarray:
        x = np.asarray(q_act_mm, dtype=float)
        return x * np.broadcast_to(np.asarray(self.factor, dtype=float), x.shape)

    def to_actuator(self, q_cable_mm: np.ndarray, state: None) -> np.ndarray:
        y = np.asarray(q_cable_mm, dtype=float)
        return y / np.broadcast_to(np.asarray(self.factor, dtype=float), y.shape)
