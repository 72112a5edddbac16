"""Candidate physical effects for model-discrepancy analysis, and two transmission effects.

Pure physics, numpy only: no I/O, no clocks. Units: mm, N, rad, g; frames: the robot base frame.

Transmission effects (:class:`~cdcr_ctl.model.cc_disk.params.ActuatorEffect`, between the drive and
the cable leaving the spool, applied by :class:`~cdcr_ctl.model.cc_disk.forward.ForwardStepper`):

* :class:`BacklashPlay` - a play (dead band) of width b in the transmission: the cable follows the
  actuator only while the actuator pushes against one side of the play,
  y = clip(y_prev, x - b/2, x + b/2)  (the "play operator" of hysteresis theory; a dead zone at
  every reversal whose width is independent of speed and tension; Yang et al. 2022 eq. 13-17 model
  the same dead zone at direction reversal).
* :class:`TransmissionScale` - the cable moves ``factor`` mm per mm the drive reports (lead or
  counts-per-mm error): y = factor * x.

Candidate effects (:class:`EffectTerm`): each is one physical term with parameters, units and a
signature, written as a change of a :class:`ModelSpec` (robot parameters, switchable effects,
tip measurement map). Every parameter vector is a *correction* of the controller's model: zero
means "the model as it is", so the same term explains an effect the model lacks (switched off)
and one it has with the wrong magnitude. A new effect is one subclass with :meth:`parameters`,
:meth:`apply` and optionally :meth:`not_applicable`; add an instance to :data:`CANDIDATES`.
"""

from __future__ import annotations

from cdcr_ctl.model.cc_disk.effect_friction_law import OtherFrictionLaw
from cdcr_ctl.model.cc_disk.effect_spec import (
    REFERENCE_DISK_MASS_G,
    REFERENCE_EA_N,
    REFERENCE_MU_DISK,
    STANDARD_GRAVITY_MM_S2,
    EffectParam,
    EffectTerm,
    FittedValue,
    ModelSpec,
    _cables,
    rotation_from_rotvec,
    rotvec_from_rotation,
)
from cdcr_ctl.model.cc_disk.effect_terms import (
    ActuatorScale,
    CableElongation,
    DiskFriction,
    GravityDirection,
    GravitySag,
    PulleyLosses,
    ReversalBacklash,
    SegmentCoupling,
    TrackerFrameOffset,
)
from cdcr_ctl.model.cc_disk.effect_tip_load import TipPayload
from cdcr_ctl.model.cc_disk.transmission_effects import (
    BacklashPlay,
    TransmissionScale,
    with_cable_play,
)

__all__ = [
    "CANDIDATES",
    "REFERENCE_DISK_MASS_G",
    "REFERENCE_EA_N",
    "REFERENCE_MU_DISK",
    "STANDARD_GRAVITY_MM_S2",
    "ActuatorScale",
    "BacklashPlay",
    "CableElongation",
    "DiskFriction",
    "EffectParam",
    "EffectTerm",
    "FittedValue",
    "GravityDirection",
    "GravitySag",
    "ModelSpec",
    "OtherFrictionLaw",
    "PulleyLosses",
    "ReversalBacklash",
    "SegmentCoupling",
    "TipPayload",
    "TrackerFrameOffset",
    "TransmissionScale",
    "_cables",
    "candidate",
    "rotation_from_rotvec",
    "rotvec_from_rotation",
    "with_cable_play",
]

#: The candidate library, in report order. Extend by appending an instance of a new subclass.
CANDIDATES: tuple[EffectTerm, ...] = (
    CableElongation(),
    DiskFriction(),
    OtherFrictionLaw(),
    ReversalBacklash(),
    SegmentCoupling(),
    GravitySag(),
    GravityDirection(),
    PulleyLosses(),
    ActuatorScale(),
    TrackerFrameOffset(),
    TipPayload(),
)


def candidate(name: str) -> EffectTerm:
    """The library term called ``name`` (KeyError listing the names otherwise)."""
    for c in CANDIDATES:
        if c.name == name:
            return c
    raise KeyError(f"no effect {name!r}; known: {', '.join(c.name for c in CANDIDATES)}")
