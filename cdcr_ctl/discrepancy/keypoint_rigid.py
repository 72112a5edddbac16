"""Is a registration error one rigid frame? The test that tells it from a pose-dependent effect.

The ``registration`` candidate of :mod:`.keypoint_effects` is one rotation and translation of the
tracker frame, fitted in closed form (Kabsch) on the rows before the hold-out cut. A frame fixed
in the lab is the same at every pose. A sag is not: on a sideways mount the weight's droop is,
to first order, a tilt and a shift of the whole arm (which a turned tracker frame also makes),
but its size follows the weight's lever arm, so the tilt that stands in for it changes with the
pose. Both may then explain the held-out rows alike (a tie by the paired test) while only one is
a frame.

The test (:func:`frame_rigidity`): the rows before the cut are split in two at the median of a
per-row *split* variable, here how far the rival candidate's fitted replay moves the tip from the
config's replay (for ``gravity``: the fitted extra sag, large where the weight is far out, small
where it hangs near the base's line); a frame is fitted on each half and each held-out row is
predicted with its own half's frame and with the other half's. Per held-out row the squared tip
error other - own, averaged in blocks of consecutive rows
(:func:`cdcr_ctl.identify.keypoint_gate.heldout_gain`), is the cost of assuming one frame for
both halves. The frame is *not rigid* when that mean exceeds ``se_factor`` standard errors and
the tracker's noise variance per row, 3 sigma^2 (sigma per axis, from the log): the two frames
then disagree at the tip by more than a noise draw, beyond their own estimation noise. The
noise floor keeps a frame rigid where the config departs from the arm by less than the noise
(the independent worlds' chain differs from constant curvature by ~0.6 mm RMS), which a
significance test alone would flag on a long log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.discrepancy.keypoint_effects import kabsch
from cdcr_ctl.identify.keypoint_gate import heldout_gain


@dataclass(frozen=True)
class Rigidity:
    """Outcome of :func:`frame_rigidity`: the two halves' frames (angle between them, deg;
    distance of their translations, mm), the paired cost of one frame for both halves on the
    held-out rows (mean mm^2, its standard error), the noise floor 3 sigma^2 (mm^2) and the
    rows of each half."""

    angle_deg: float
    shift_mm: float
    cost_mm2: float
    se_mm2: float
    floor_mm2: float
    n_fit: tuple[int, int]
    n_held: int
    se_factor: float

    @property
    def rigid(self) -> bool:
        beyond = self.cost_mm2 > self.se_factor * self.se_mm2 and self.cost_mm2 > self.floor_mm2
        return not beyond

    def line(self, split: str) -> str:
        verdict = (
            "one frame fits both halves"
            if self.rigid
            else "NOT ONE FRAME: what it absorbs changes with the pose"
        )
        return (
            f"registration fitted on the halves of the rows split by {split} "
            f"({self.n_fit[0]}/{self.n_fit[1]} rows): frames {self.angle_deg:.2g} deg and "
            f"{self.shift_mm:.2g} mm apart; the other half's frame costs the {self.n_held} "
            f"held-out rows {self.cost_mm2:.3g} mm^2 (SE {self.se_mm2:.2g}; noise 3 sigma^2 "
            f"{self.floor_mm2:.2g} mm^2): {verdict}"
        )


def frame_rigidity(
    tip_model: np.ndarray,
    tip: np.ndarray,
    fit: np.ndarray,
    held: np.ndarray,
    split: np.ndarray,
    noise_mm: float,
    se_factor: float,
) -> Rigidity:
    """The test of the module docstring. ``tip_model`` (N, 3) mm: the model's tips the frame
    maps (the config's replay for the registration candidate alone); ``tip`` (N, 3) mm: the
    logged tips; ``fit``/``held``: boolean row masks (rows in time order); ``split`` (N,): the
    variable whose median (over the fitted rows) cuts the rows in two; ``noise_mm``: the
    tracker noise per axis."""
    ok = np.all(np.isfinite(tip_model), axis=1) & np.all(np.isfinite(tip), axis=1)
    ok &= np.isfinite(split)
    f = fit & ok
    upper = split > np.median(split[f])
    frames = []
    for half in (upper, ~upper):
        frames.append(kabsch(tip_model[f & half], tip[f & half]))
    (Ra, ta), (Rb, tb) = frames
    h = np.flatnonzero(held & ok)
    m = tip_model[h]
    pa, pb = m @ Ra.T + ta, m @ Rb.T + tb
    up = upper[h][:, None]
    own = np.where(up, pa, pb) - tip[h]
    other = np.where(up, pb, pa) - tip[h]
    cost, se = heldout_gain(np.sum(other * other, axis=1), np.sum(own * own, axis=1))
    cos = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return Rigidity(
        math.degrees(math.acos(max(-1.0, min(1.0, cos)))),
        float(np.linalg.norm(ta - tb)),
        cost,
        se,
        3.0 * noise_mm**2,
        (int((f & upper).sum()), int((f & ~upper).sum())),
        int(h.size),
        se_factor,
    )
