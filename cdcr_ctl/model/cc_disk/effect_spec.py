"""Model specification and the effect-term interface of the discrepancy candidates.

Pure numpy: :class:`ModelSpec` (robot parameters, switchable effects, tip measurement map),
:class:`EffectParam`, :class:`FittedValue` and the :class:`EffectTerm` ABC every candidate in
:mod:`cdcr_ctl.model.cc_disk.effect_terms` implements, plus the reference constants (Qi et al. 2023
section 3) and the rotation-vector helpers (Rodrigues) of the tracker-alignment term.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams

#: Reference axial stiffness (N) when the config has rigid cables: 0.8 mm PE cable,
#: E = 4960 MPa (Qi et al. 2023 section 3) -> EA = 4960 * pi * 0.4^2 = 2493 N.
REFERENCE_EA_N = 2493.0
#: Reference disk mass (g) when the config gives none (Qi et al. 2023 aluminium disks, ~0.8 g).
REFERENCE_DISK_MASS_G = 0.8
#: Reference disk-hole friction coefficient when the config gives none (PE cable in aluminium
#: holes, the middle of Qi et al. 2023's identified values 0.26-0.31).
REFERENCE_MU_DISK = 0.28
#: Standard gravity in the base frame when the config's gravity vector is zero (mm/s^2).
STANDARD_GRAVITY_MM_S2 = (0.0, 0.0, -9810.0)


# ---------------------------------------------------------------------- model specification
def rotation_from_rotvec(rotvec_rad: np.ndarray | tuple[float, ...]) -> np.ndarray:
    """Rodrigues: rotation matrix of the rotation vector (axis * angle, rad)."""
    w = np.asarray(rotvec_rad, dtype=float)
    a = float(np.linalg.norm(w))
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if a < 1e-12:
        return np.eye(3) + W
    return np.eye(3) + math.sin(a) / a * W + (1.0 - math.cos(a)) / a**2 * (W @ W)


@dataclass(frozen=True)
class ModelSpec:
    """Everything a forward simulation of a logged run needs, as the model believes it.

    ``params``/``effects``: the robot and its switchable effects (the transmission effects in
    ``effects.actuator``). ``tip_rotvec_rad``/``tip_translation_mm``: the tracker-alignment
    error, a rigid map applied to the model's tip: p_measured = R(rotvec) p_model + t (base
    frame, mm). ``coupling_gain``: weight of the distal-cable load on proximal segments (eq.
    11-15); the forward model knows only 0 (``effects.coupling`` off) and 1 (on), so a value in
    between is evaluated as the blend of the two solutions (see :class:`SegmentCoupling`).
    ``friction_law``: the disk friction's law when it is not the capstan law
    (:mod:`~cdcr_ctl.model.cc_disk.friction_law`; None: the model's own).
    """

    params: RobotParams
    effects: Effects
    tip_rotvec_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tip_translation_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    coupling_gain: float | None = None
    friction_law: FrictionLawShape | None = None

    def tip_map(self, tip_mm: np.ndarray) -> np.ndarray:
        """Model tips (..., 3) -> what the tracker reports in the base frame (mm)."""
        R = rotation_from_rotvec(self.tip_rotvec_rad)
        return np.asarray(tip_mm, dtype=float) @ R.T + np.asarray(self.tip_translation_mm)


@dataclass(frozen=True)
class EffectParam:
    """One parameter of an effect term: name, unit, finite-difference / typical step, bounds."""

    name: str
    unit: str
    step: float
    lower: float = -math.inf
    upper: float = math.inf


@dataclass(frozen=True)
class FittedValue:
    """A physical quantity a fitted term implies, e.g. the new ``mu_disk`` of cable c1."""

    what: str  # e.g. "cable", "pulley", "segment", "drive", "tracker", "model_effects"
    item: str  # name of the cable / pulley / segment, or "" for global quantities
    key: str  # config-like key, e.g. "mu_disk", "E_scale", "backlash_mm"
    value: float | list[float] | bool


class EffectTerm(ABC):
    """A candidate physical effect: parameters, how it changes the model, and its signature.

    ``kind``: ``"model"`` (needs a forward simulation per evaluation), ``"measurement"`` (a map
    of the model's outputs; no simulation), ``"blend"`` (a linear blend of the model with the
    effect switched on, see :class:`SegmentCoupling`). ``needs_tensions``: the term can only be
    identified with measured tensions (skipped, with a note, for logs without them).
    """

    name: ClassVar[str]
    title: ClassVar[str]
    signature: ClassVar[str]
    reference: ClassVar[str]
    kind: ClassVar[str] = "model"
    needs_tensions: ClassVar[bool] = False
    #: The effect this one refines (contains as a special case): compared only when that one
    #: leads the first comparison (:func:`cdcr_ctl.discrepancy.selection.refinements`).
    refines: ClassVar[str | None] = None
    #: Effects whose lead in a first comparison (this one's included) calls for this term's
    #: far secant steps (:meth:`far_steps`): compared again with them.
    far_when: ClassVar[tuple[str, ...]] = ()

    def not_applicable(self, base: ModelSpec) -> str | None:
        """Why this term cannot act on ``base`` (None when it can)."""
        return None

    @abstractmethod
    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        """The term's parameters for this model (zero = the model unchanged)."""

    @abstractmethod
    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        """The model with the term's correction ``values`` (one per parameter) applied."""

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        """Physical quantities implied by ``values`` (for the config fragment)."""
        return []

    def far_steps(self, base: ModelSpec) -> tuple[tuple[float, ...], ...]:
        """Far secant steps per parameter (one tuple each, in the parameter's unit), tried
        beside its small ``step`` when a correction can lie far from zero, where the slope at
        zero points elsewhere (see :func:`cdcr_ctl.discrepancy.design.build_design`). Empty
        tuples by default."""
        return tuple(() for _ in self.parameters(base))


def _cables(params: RobotParams, **changes_per_cable: list) -> RobotParams:
    cables = list(params.cables)
    for key, vals in changes_per_cable.items():
        cables = [replace(c, **{key: v}) for c, v in zip(cables, vals, strict=True)]
    return replace(params, cables=tuple(cables))


def rotvec_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_from_rotvec` for angles below pi (rad)."""
    c = max(-1.0, min(1.0, (float(np.trace(R)) - 1.0) / 2.0))
    a = math.acos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if a < 1e-9:
        return 0.5 * v
    return a / (2.0 * math.sin(a)) * v
