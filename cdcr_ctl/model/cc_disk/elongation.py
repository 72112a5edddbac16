"""Cable elongation from one integral along the whole cable (Qi et al. 2023 eq. 33-36).

Hooke's law (eq. 33) integrated over the cable from the actuator to the anchor, relative to the
straight pretensioned reference (NOTES: the symbols of eq. 34-35 are inconsistent; everything
follows from this one integral):

    delta = (1/EA) * integral (T(s) - T0) ds                                  (mm)

Material conservation gives the compatibility used by the forward model: the actuator takes in
q_act = q_geom + delta (to first order in T/EA). Pieces of the path:

* free straight runs (actuator -> pulley -> ... -> robot base), length L_free/(P+1) each, with the
  run's constant tension;
* pulley wraps (eq. 34-35): (R + r_s) * integral over the wrap of (T(phi) - T0) dphi, T(phi) the
  eq. 29 profile (:meth:`cdcr_ctl.model.shared.capstan.PulleyTransfer.stretch_integral`);
* disk-hole spans (eq. 36): the span tensions of eq. 23 times the spans' reference lengths
  l_i/n_i (the length change with the pose multiplies a strain: second order, dropped). For a
  continuous wrap with curvature theta/l this is eq. 36, T_d l (exp(s mu theta) - 1)/(s mu theta).

The material drawn out of the robot through the base hole is w = q_geom + delta_in, and
q_act = w + delta_out (delta split at the base hole). Rigid cables (EA -> inf) give delta = 0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.model.cc_disk.params import CableParams, RobotParams, cable_radius_mm
from cdcr_ctl.model.cc_disk.routing import wrap_angles
from cdcr_ctl.model.shared.capstan import PulleyTransfer
from cdcr_ctl.model.shared.friction import propagate


def piecewise(tensions_N: Sequence[float], lengths_mm: Sequence[float], T0_N: float, EA_N: float):
    """(1/EA) sum (T_j - T0) L_j (mm): the integral for piecewise-constant tension."""
    if math.isinf(EA_N):
        return 0.0
    T = np.asarray(tensions_N, dtype=float)
    L = np.asarray(lengths_mm, dtype=float)
    return float(np.sum((T - T0_N) * L) / EA_N)


def continuous_disk(
    T_distal_N: float, mu: float, s: float, theta: float, length_mm: float, T0_N: float, EA_N: float
) -> float:
    """Eq. 36 (corrected): stretch of one segment with a continuous capstan wrap theta (mm).

    T(x) = T_d exp(s mu theta (l - x)/l) for x from the base, so
    integral T dx = T_d l (exp(s mu theta) - 1)/(s mu theta) (-> T_d l at s mu theta = 0).
    """
    if math.isinf(EA_N):
        return 0.0
    y = s * mu * theta
    mean = 1.0 if y == 0.0 else math.expm1(y) / y
    return (T_distal_N * mean - T0_N) * length_mm / EA_N


@dataclass(frozen=True)
class CableProfile:
    """Tension along one cable, actuator to anchor (reference implementation, numpy).

    ``runs_N``: the P+1 free runs, actuator first; ``pulleys``: the P (actuator-side, robot-side)
    tension pairs; ``spans_N``: the piece tensions inside the robot base first (eq. 23) and
    ``span_lengths_mm`` their reference lengths (0 for disk channels).
    """

    runs_N: tuple[float, ...]
    run_length_mm: float
    pulleys: tuple[tuple[float, float], ...]
    spans_N: np.ndarray
    span_lengths_mm: np.ndarray
    T_base_N: float

    @property
    def T_actuator_N(self) -> float:
        return self.runs_N[0]

    @property
    def T_distal_N(self) -> float:
        return float(self.spans_N[-1])


def cable_profile(
    psi: np.ndarray,
    params: RobotParams,
    k: int,
    T_distal_N: float,
    s: float,
    transfers: Sequence[PulleyTransfer],
) -> CableProfile:
    """Tension profile of cable k from its distal tension and friction state (reference).

    Disk holes: eq. 23 hole by hole over the exact chord wrap angles
    (:func:`cdcr_ctl.model.cc_disk.routing.wrap_angles`); pulleys: the improved capstan tables
    ``transfers`` (one per pulley, actuator -> robot order).
    """
    c = params.cables[k]
    wraps = wrap_angles(psi, params, k)
    spans, T_base = propagate(T_distal_N, wraps, c.mu_disk, s)
    lengths = []
    for i in range(c.segment + 1):
        seg = params.segments[i]
        thick = seg.disk_thickness_mm > 0.0
        for _ in range(seg.n_disks):
            lengths.append(seg.length_mm / seg.n_disks)
            if thick:
                lengths.append(0.0)
    if params.segments[c.segment].disk_thickness_mm > 0.0:
        lengths = lengths[:-1]
    lengths_arr = np.array(lengths)
    T = T_base
    runs = [T]
    pulleys = []
    for tr in reversed(transfers):
        T_act = tr.to_actuator(T, s)
        pulleys.append((T_act, T))
        T = T_act
        runs.append(T)
    run_len = c.free_length_mm / (len(transfers) + 1)
    return CableProfile(
        runs_N=tuple(reversed(runs)),
        run_length_mm=run_len,
        pulleys=tuple(reversed(pulleys)),
        spans_N=spans,
        span_lengths_mm=lengths_arr,
        T_base_N=T_base,
    )


def split_elongation(
    profile: CableProfile, cable: CableParams, s: float, transfers: Sequence[PulleyTransfer]
) -> tuple[float, float]:
    """(delta_in, delta_out) in mm: stretch inside the robot and between actuator and base."""
    EA, T0 = cable.EA_N, cable.pretension_N
    if math.isinf(EA):
        return 0.0, 0.0
    d_in = piecewise(profile.spans_N, profile.span_lengths_mm, T0, EA)
    d_out = piecewise(profile.runs_N, [profile.run_length_mm] * len(profile.runs_N), T0, EA)
    for tr, (Ta, Tb) in zip(transfers, profile.pulleys, strict=True):
        d_out += tr.stretch_integral(Ta, Tb, s, T0) / EA
    return d_in, d_out


def transfers_for(cable: CableParams, points: int = 121) -> list[PulleyTransfer]:
    """One :class:`PulleyTransfer` per pulley of ``cable`` (actuator -> robot)."""
    return [
        PulleyTransfer(p.radius_mm, p.wrap_angle_rad, p.alpha, p.n, cable_radius_mm(cable), points)
        for p in cable.pulleys
    ]
