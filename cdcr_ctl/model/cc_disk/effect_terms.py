"""The candidate physical effects of model-discrepancy analysis, one :class:`EffectTerm` each.

Pure physics, numpy only. Each term is a correction of the controller's model (zero = the model
as it is). Qi et al. 2023: cable elongation (eq. 33-36), disk friction (eq. 16-24), segment
coupling (eq. 11-15), gravity sag and direction (eq. 7-9), pulley losses (eq. 25-32); Yang et
al. 2022: reversal backlash (eq. 13-17), actuator scale (eq. 3); and the tracker frame offset.
The library :data:`~cdcr_ctl.model.cc_disk.effects.CANDIDATES` lists them.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

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
from cdcr_ctl.model.cc_disk.params import CableParams
from cdcr_ctl.model.cc_disk.transmission_effects import BacklashPlay, TransmissionScale


class CableElongation(EffectTerm):
    """Elastic cable stretch (Hooke, eq. 33-36) with a corrected compliance.

    Parameter ``d_compliance`` (dimensionless): 1/EA_k = (kappa0 + d) / EA_cfg_k, kappa0 = 1 when
    the model already has elastic cables, 0 when it has rigid ones (then the term switches
    elongation on). Signature: the tip error grows with tension (stretch = integral of T - T0
    along the cable), loops of lost motion at reversals when friction moves the tension.
    """

    name = "cable_elongation"
    title = "cable elongation"
    signature = "error grows with cable tension; lost motion proportional to tension changes"
    reference = "Qi et al. 2023 eq. 33-36"

    def _kappa0(self, base: ModelSpec) -> float:
        rigid = (not base.effects.elongation) or all(math.isinf(c.EA_N) for c in base.params.cables)
        return 0.0 if rigid else 1.0

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        k0 = self._kappa0(base)
        return (EffectParam("d_compliance", "1 (x nominal 1/EA)", 0.5, -0.95 * k0, 10.0),)

    def _ea_ref(self, c: CableParams) -> float:
        return REFERENCE_EA_N if math.isinf(c.EA_N) else c.EA_N

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        kappa = self._kappa0(base) + float(values[0])
        if kappa <= 1e-9:
            return replace(base, effects=replace(base.effects, elongation=False))
        EA = [self._ea_ref(c) / kappa for c in base.params.cables]
        return replace(
            base,
            params=_cables(base.params, EA_N=EA),
            effects=replace(base.effects, elongation=True),
        )

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        kappa = self._kappa0(base) + float(values[0])
        out = [
            FittedValue("cable", c.name, "EA_N", self._ea_ref(c) / max(kappa, 1e-9))
            for c in base.params.cables
        ]
        if not base.effects.elongation:
            out.append(FittedValue("model_effects", "", "elongation", True))
        return out


class DiskFriction(EffectTerm):
    """Capstan friction of the cables in the disk holes (eq. 16-24) with a corrected mu.

    Parameter ``d_mu_scale`` (dimensionless, common to all cables): mu_k = (a0 + d) * mu_ref_k,
    a0 = 1 when the model has disk friction on with some ``mu_disk`` > 0, else 0 (a switch on
    with every mu 0 is a model without disk friction: d = 0 must leave it so); mu_ref_k = the
    config's ``mu_disk`` of cable k (the cables' ratios are kept: they come from the same holes
    and the same cable), or :data:`REFERENCE_MU_DISK` for every cable when the config gives
    none. The refit evaluates the forward model itself with the friction switched on
    (direction-dependent capstan factors per cable and disk, stick at reversals, the friction
    state carried from sample to sample as the simulated world does), not a linearisation.
    Signature: direction-dependent (hysteresis), growing with the bend (the wrap angles add up
    to about theta), stick at reversals.
    """

    name = "disk_friction"
    title = "capstan friction in the disks"
    signature = "direction-dependent error (hysteresis) that grows with the bend angle"
    reference = "Qi et al. 2023 eq. 16-24"

    def _a0(self, base: ModelSpec) -> float:
        on = base.effects.disk_friction and any(c.mu_disk > 0 for c in base.params.cables)
        return 1.0 if on else 0.0

    def _mu_ref(self, base: ModelSpec) -> np.ndarray:
        mu = np.array([c.mu_disk for c in base.params.cables], dtype=float)
        return mu if np.any(mu > 0) else np.full(len(mu), REFERENCE_MU_DISK)

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        a0 = self._a0(base)
        return (EffectParam("d_mu_scale", "1 (x configured mu_disk)", 0.5, -a0, 6.0),)

    def _mu(self, base: ModelSpec, values: np.ndarray) -> np.ndarray:
        return max(self._a0(base) + float(values[0]), 0.0) * self._mu_ref(base)

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        mu = self._mu(base, values)
        if not np.any(mu > 0):
            return replace(base, effects=replace(base.effects, disk_friction=False))
        return replace(
            base,
            params=_cables(base.params, mu_disk=mu.tolist()),
            effects=replace(base.effects, disk_friction=True),
        )

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        out = [
            FittedValue("cable", c.name, "mu_disk", float(m))
            for c, m in zip(base.params.cables, self._mu(base, values), strict=True)
        ]
        if not base.effects.disk_friction:
            out.append(FittedValue("model_effects", "", "disk_friction", True))
        return out


class ReversalBacklash(EffectTerm):
    """Lost motion (play) between drive and cable, one correction for all cables
    (:class:`BacklashPlay`).

    Parameter ``backlash_mm`` (mm, >= 0): added to each cable's configured play
    (``CableParams.backlash_mm``, 0 when the config has none). Signature: a dead zone at every
    reversal whose width is independent of speed and tension; the error keeps the sign of the
    last motion.
    """

    name = "backlash"
    title = "backlash / dead zone at reversals"
    signature = "dead zone after each reversal, width independent of speed and tension"
    reference = "Yang et al. 2022 eq. 13-17 (dead zone at reversal)"

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        return (EffectParam("backlash_mm", "mm", 0.2, 0.0, 20.0),)

    def _widths(self, base: ModelSpec, values: np.ndarray) -> tuple[float, ...]:
        b = max(float(values[0]), 0.0)
        return tuple(c.backlash_mm + b for c in base.params.cables)

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        if max(float(values[0]), 0.0) == 0.0:
            return base
        w = self._widths(base, values)
        # the play sits where the config's was, else after the drive-side effects (a scale)
        old = base.effects.actuator
        at = next((i for i, e in enumerate(old) if isinstance(e, BacklashPlay)), len(old))
        rest = tuple(e for e in old if not isinstance(e, BacklashPlay))
        params = _cables(base.params, backlash_mm=list(w))
        act = (*rest[:at], BacklashPlay(w), *rest[at:])
        return replace(base, params=params, effects=replace(base.effects, actuator=act))

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        return [
            FittedValue("cable", c.name, "backlash_mm", w)
            for c, w in zip(base.params.cables, self._widths(base, values), strict=True)
        ]


class SegmentCoupling(EffectTerm):
    """Load of the distal cables on the proximal segments they cross (eq. 11-15).

    Parameter ``d_gain``: coupling gain lambda = lambda0 + d, lambda0 = 1 when the model has
    coupling on, 0 when off. The forward model switches the term on or off; a gain in between is
    the linear blend y = (1 - lambda) y_off + lambda y_on. Needs two or more segments.
    Signature: the proximal segments' error follows the distal segments' bend.
    """

    name = "coupling"
    title = "coupling between segments"
    signature = "proximal error follows the distal segments' bend and tensions"
    reference = "Qi et al. 2023 eq. 11-15"
    kind = "blend"

    def not_applicable(self, base: ModelSpec) -> str | None:
        if base.params.n_segments < 2:
            return "one segment: no distal cables cross another segment"
        return None

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        lam0 = 1.0 if base.effects.coupling else 0.0
        return (EffectParam("d_gain", "1", 1.0 - 2.0 * lam0, -lam0, 2.0 - lam0),)

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        lam0 = 1.0 if base.effects.coupling else 0.0
        lam = lam0 + float(values[0])
        return replace(base, coupling_gain=lam)

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        lam0 = 1.0 if base.effects.coupling else 0.0
        lam = lam0 + float(values[0])
        # the controller's model: coupling on with this gain (control.model_effects)
        return [
            FittedValue("model_effects", "", "coupling", bool(lam > 0.0)),
            FittedValue("model_effects", "", "coupling_gain", min(max(lam, 0.0), 2.0)),
        ]


class GravitySag(EffectTerm):
    """Weight of the disks (generalised forces of the statics) with a corrected mass.

    Parameter ``d_mass_scale``: disk masses m_i = (a0 + d) m_ref_i, a0 = 1 when the model has
    gravity on with nonzero masses, else 0 (m_ref = the config masses, or
    :data:`REFERENCE_DISK_MASS_G`; gravity vector from the config, standard gravity along -z if
    the config's is zero). Signature: depends on the pose relative to gravity (largest when the
    robot bends sideways, sign set by the bending direction).
    """

    name = "gravity_sag"
    title = "gravity sag"
    signature = "error depends on the pose relative to gravity (bending direction vs g)"
    reference = "Qi et al. 2023 eq. 7-9 (external load W_e); statics.gravity_force"

    def _a0(self, base: ModelSpec) -> float:
        p = base.params
        on = base.effects.gravity and any(s.disk_mass_g > 0 for s in p.segments)
        return 1.0 if on and np.linalg.norm(p.gravity_mm_s2) > 0 else 0.0

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        a0 = self._a0(base)
        return (EffectParam("d_mass_scale", "1 (x disk mass)", 1.0, -a0, 50.0),)

    def _refs(self, base: ModelSpec) -> list[float]:
        return [
            s.disk_mass_g if s.disk_mass_g > 0 else REFERENCE_DISK_MASS_G
            for s in base.params.segments
        ]

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        a = max(self._a0(base) + float(values[0]), 0.0)
        p = base.params
        g = p.gravity_mm_s2 if np.linalg.norm(p.gravity_mm_s2) > 0 else STANDARD_GRAVITY_MM_S2
        segs = tuple(
            replace(s, disk_mass_g=a * m) for s, m in zip(p.segments, self._refs(base), strict=True)
        )
        return replace(
            base,
            params=replace(p, segments=segs, gravity_mm_s2=tuple(g)),
            effects=replace(base.effects, gravity=a > 0),
        )

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        a = max(self._a0(base) + float(values[0]), 0.0)
        out = [
            FittedValue("segment", s.name, "disk_mass_g", a * m)
            for s, m in zip(base.params.segments, self._refs(base), strict=True)
        ]
        if not base.effects.gravity:
            out.append(FittedValue("model_effects", "", "gravity", True))
        return out


class GravityDirection(EffectTerm):
    """The mount direction: gravity in the base frame turned away from the config's vector.

    Parameters ``tilt_x``/``tilt_y`` (rad): g_new = R(w) g_cfg with the rotation vector
    w = tilt_x e_1 + tilt_y e_2, e_1 and e_2 the mount's x and y axes: the base x and y axes
    carried by the shortest rotation from -z onto the config's gravity direction (the base x and
    y themselves when the config says -z; standard gravity along -z if the config's is zero).
    Both axes are perpendicular to g_cfg, so every w turns g by |w| (a turn about g itself
    would change nothing), and with |w| up to pi the turned vector reaches every direction on
    the sphere: polar angle |w| from g_cfg, azimuth the direction of w. The size of g is kept
    (the mount is turned, gravity is not stronger). When the model has no disk mass or gravity
    off, the reference masses (:data:`REFERENCE_DISK_MASS_G`) carry the sag. Signature: a sag
    whose direction in the base frame is fixed and not the config's (sideways for a robot whose
    config says upright): the error depends on the bending direction relative to the true
    gravity, not on time.
    """

    name = "gravity_direction"
    title = "gravity direction (mount tilt)"
    signature = "sag towards a fixed direction other than the config's gravity vector"
    reference = "Qi et al. 2023 eq. 7-9 (external load W_e) with the mount direction fitted"
    far_when = ("gravity_direction", "gravity_sag")

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        return (
            EffectParam("tilt_x", "rad", 0.05, -math.pi, math.pi),
            EffectParam("tilt_y", "rad", 0.05, -math.pi, math.pi),
        )

    def far_steps(self, base: ModelSpec) -> tuple[tuple[float, ...], ...]:
        """Quarter turns both ways about each mount axis, and the half turn about x (g
        reversed: a robot hanging where the config says upright). Near zero the slope of a
        turn is a sideways sag, at right angles to the reversed sag of a half turn."""
        q = math.pi / 2
        return ((q, -q, math.pi), (q, -q))

    def _gravity(self, base: ModelSpec, values: np.ndarray) -> np.ndarray:
        g = np.asarray(base.params.gravity_mm_s2, dtype=float)
        if np.linalg.norm(g) == 0:
            g = np.asarray(STANDARD_GRAVITY_MM_S2)
        e1, e2 = mount_axes(g)
        R = rotation_from_rotvec(float(values[0]) * e1 + float(values[1]) * e2)
        return R @ g

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        p = base.params
        segs = p.segments
        if not (base.effects.gravity and any(s.disk_mass_g > 0 for s in segs)):
            segs = tuple(
                replace(s, disk_mass_g=s.disk_mass_g or REFERENCE_DISK_MASS_G) for s in segs
            )
        g = tuple(float(v) for v in self._gravity(base, values))
        return replace(
            base,
            params=replace(p, segments=segs, gravity_mm_s2=g),
            effects=replace(base.effects, gravity=True),
        )

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        g = [round(float(v), 2) for v in self._gravity(base, values)]
        out = [FittedValue("robot", "", "gravity_mm_s2", g)]
        if not (base.effects.gravity and any(s.disk_mass_g > 0 for s in base.params.segments)):
            # the sag was carried by the reference masses (apply): the config needs them too
            out += [
                FittedValue(
                    "segment", s.name, "disk_mass_g", s.disk_mass_g or REFERENCE_DISK_MASS_G
                )
                for s in base.params.segments
            ]
        if not base.effects.gravity:
            out.append(FittedValue("model_effects", "", "gravity", True))
        return out


def mount_axes(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mount's x and y axes in the base frame for gravity ``g`` (any size > 0).

    The base x and y axes turned by the shortest rotation that takes -z onto g/|g|; for g
    along +z (a robot hanging from its base upside down) the half turn about x. Both are unit
    vectors perpendicular to g (and to each other).
    """
    d = np.asarray(g, dtype=float) / float(np.linalg.norm(g))
    down = np.array([0.0, 0.0, -1.0])
    axis = np.cross(down, d)
    s = float(np.linalg.norm(axis))
    c = float(down @ d)
    if s < 1e-12:
        R = np.eye(3) if c > 0 else rotation_from_rotvec((math.pi, 0.0, 0.0))
    else:
        R = rotation_from_rotvec(axis / s * math.atan2(s, c))
    return R[:, 0], R[:, 1]


class PulleyLosses(EffectTerm):
    """Friction on the guide pulleys (improved capstan, eq. 25-32) with a corrected alpha.

    Parameter ``d_alpha`` (common to all pulleys): alpha_p = alpha0_p + d, alpha0 = 0 when the
    model has pulley friction off. Signature: the tension between actuator and robot base
    differs by a direction-dependent factor; lost motion from the extra stretch of the free
    cable. Identified from the tensions: skipped for logs without them.
    """

    name = "pulley_losses"
    title = "pulley losses"
    signature = "direction-dependent tension loss between actuator and robot base"
    reference = "Qi et al. 2023 eq. 25-32"
    needs_tensions = True

    def not_applicable(self, base: ModelSpec) -> str | None:
        if not any(c.pulleys for c in base.params.cables):
            return "the config routes no cable over a pulley"
        return None

    def _alpha0(self, base: ModelSpec) -> dict[str, float]:
        on = base.effects.pulley_friction
        return {p.name: (p.alpha if on else 0.0) for c in base.params.cables for p in c.pulleys}

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        return (EffectParam("d_alpha", "1", 0.1, -min(self._alpha0(base).values()), 2.0),)

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        a0 = self._alpha0(base)
        d = float(values[0])
        cables = tuple(
            replace(
                c,
                pulleys=tuple(replace(p, alpha=max(a0[p.name] + d, 0.0)) for p in c.pulleys),
            )
            for c in base.params.cables
        )
        return replace(
            base,
            params=replace(base.params, cables=cables),
            effects=replace(base.effects, pulley_friction=True),
        )

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        d = float(values[0])
        out = [
            FittedValue("pulley", name, "alpha", max(a + d, 0.0))
            for name, a in sorted(self._alpha0(base).items())
        ]
        if not base.effects.pulley_friction:
            out.append(FittedValue("model_effects", "", "pulley_friction", True))
        return out


class ActuatorScale(EffectTerm):
    """Counts-per-mm / lead error of each drive (:class:`TransmissionScale`).

    Parameters ``d_scale_<cable>``: the cable moves (1 + d) mm per reported mm. Signature: the
    error grows with each cable's displacement from home, independent of tension and direction.
    The corrected counts_per_mm is counts_per_mm / (1 + d).
    """

    name = "actuator_scale"
    title = "actuator scale error (lead / counts per mm)"
    signature = "error proportional to each cable's displacement, no hysteresis"
    reference = "Yang et al. 2022 eq. 3 / fuel-tank arm eq. 9 (pulses per mm)"

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        return tuple(
            EffectParam(f"d_scale_{c.name}", "1", 0.02, -0.5, 0.5) for c in base.params.cables
        )

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        f = tuple(1.0 + float(v) for v in values)
        act = (TransmissionScale(f), *base.effects.actuator)
        return replace(base, effects=replace(base.effects, actuator=act))

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        return [
            FittedValue("drive_of_cable", c.name, "counts_per_mm_factor", 1.0 / (1.0 + float(v)))
            for c, v in zip(base.params.cables, values, strict=True)
        ]


class TrackerFrameOffset(EffectTerm):
    """A constant rigid error of the tracker alignment (base_from_tracker).

    Parameters: rotation vector (rad) and translation (mm) of p_measured = R p_model + t.
    Signature: a constant rigid transform of the whole tip path (offset constant in time,
    rotation error growing with the distance from the base origin). No simulation needed.
    """

    name = "tracker_offset"
    title = "tracker frame offset"
    signature = "constant rigid transform between model and measured tip paths"
    reference = "rigid registration (tracker alignment)"
    kind = "measurement"

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        rot = tuple(EffectParam(f"rot_{a}", "rad", 0.01) for a in "xyz")
        return rot + tuple(EffectParam(f"t_{a}", "mm", 1.0) for a in "xyz")

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        v = [float(x) for x in values]
        R0 = rotation_from_rotvec(base.tip_rotvec_rad)
        R = rotation_from_rotvec(v[:3]) @ R0
        t = rotation_from_rotvec(v[:3]) @ np.asarray(base.tip_translation_mm) + np.asarray(v[3:])
        return replace(
            base,
            tip_rotvec_rad=tuple(rotvec_from_rotation(R).tolist()),
            tip_translation_mm=tuple(float(x) for x in t),
        )

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        s = self.apply(base, values)
        return [
            FittedValue("tracker", "", "model_to_measured_rotvec_rad", list(s.tip_rotvec_rad)),
            FittedValue(
                "tracker", "", "model_to_measured_translation_mm", list(s.tip_translation_mm)
            ),
        ]
