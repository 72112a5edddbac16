"""Which model parameters a logged sweep can identify, and how each is fitted.

A :class:`FitParameter` is one fitted scalar mapped onto one or more
:class:`~cdcr_ctl.model.cc_disk.identification.ParamRef` (several when tied: identical pulleys in
series cannot be told apart, so they share one α and one n). :func:`plan_parameters` applies the
rules below to the data present and returns the parameters to fit and, for the others, why not.

Identifiability (what shows the parameter in the data; derivations in :mod:`.estimator`):

* μ_k, disk-hole friction of cable k (eq. 16-24, 38): the ratio of its tension between pulling
  in and paying out at the same pose, growing with the wrap (≈ θ). Needs a load cell on cable k,
  the tip (the pose the wrap depends on) and both motion directions.
* EI_i, backbone of segment i (eq. 8-10): the moment balance between the measured tensions and
  the measured bend. Needs load cells and the tip, with segment i bent. Without load cells only
  the ratio EI/EA shows (a stiffer backbone and a stiffer cable give the same lost motion).
* EA_k and pretension T0_k (eq. 33-36): cable compatibility q_act = q_geom(pose) + δ, with
  δ = (∫T ds - T0 L_k)/EA_k linear in the measured tension level: EA_k from the slope, T0_k from
  the offset. Needs drive feedback, the tip (q_geom of the true pose) and a load cell on cable k.
* b_k, lost motion (dead zone) between drive k and its cable (Yang et al. 2022 eq. 13-17): the
  drive stands b_k/2 ahead of the cable in the direction of its last motion, so the compatibility
  residual of the dwells after pulling in and after paying out differ by b_k at one pose (EA and
  T0 change it with the tension, not with the direction). Needs drive feedback, the tip and both
  motion directions; it is fitted with or without a load cell.
* Mount tilt (gravity direction), two angles ``tilt_x``/``tilt_y`` (deg) turning the config's
  gravity vector about the base x and y axes (g = R(rotvec = (tilt_x, tilt_y, 0)) g_cfg, its
  size kept; the parametrisation of :class:`cdcr_ctl.model.cc_disk.effect_terms.GravityDirection`):
  the disk weights enter the moment balance (eq. 7-9, external load W_e) along the true
  gravity, so a mount that is not where the config says leaves a moment residual that depends
  on the bending direction. Needs the tip, a load cell (the moment balance) and disks with
  mass in a model with gravity on. Written back as ``robot.gravity_mm_s2``.
* Pulley α (and n) (eq. 25-32): with load cells at the actuator, the ratio of actuator tension
  to the tension entering the robot (inferred from the moment balance); the friction exponent n
  from how that ratio changes with the tension level. With load cells at the robot base the
  pulleys only show through the stretch of the cable outside the robot (a second-order effect
  next to EA): α is tried and kept only if its 95 % interval is narrow; n is not fitted.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.identify.dwell import DwellPoint
from cdcr_ctl.model.cc_disk.effect_spec import STANDARD_GRAVITY_MM_S2, rotation_from_rotvec
from cdcr_ctl.model.cc_disk.identification import ParamRef, get_value, with_values
from cdcr_ctl.model.cc_disk.params import Effects, Location, RobotParams

#: Kinds of fitted parameters, in report order.
KINDS = ("EI", "mu", "EA", "pretension", "backlash", "gravity_tilt", "pulley_alpha", "pulley_n")
#: Kinds fitted from the force side (tensions, moment balance) in the first stage.
FORCE_KINDS = frozenset({"EI", "mu", "gravity_tilt"})
#: Bound of a fitted mount tilt (deg): beyond it the robot hangs sideways, not a tilted mount.
MAX_TILT_DEG = 60.0
#: A mount tilt whose 95 % half-interval exceeds this (deg) is reported as poorly identified
#: (a tilt, nominal 0, has no relative error): 2 deg turns the disk weights' moment by
#: sin 2 deg = 3.5 % of its size, about the load-cell noise's share of it on the default rig.
TILT_CI_DEG = 2.0
#: A segment whose dwells span less bend than this (rad) shows no stiffness.
MIN_BEND_RANGE_RAD = 0.2


@dataclass(frozen=True)
class FitParameter:
    """One fitted scalar. ``refs[j]`` gets ``value * scales[j] + offsets[j]`` (natural units;
    ``offsets`` empty means zeros: a hole-angle offset of a segment is value 0 + nominal angles).

    ``name`` is the report name (``c1.mu_disk``, ``seg1.EI_Nmm2``, ``pulleys.alpha``); ``kind``
    one of :data:`KINDS`; ``index`` the cable/segment index (-1 for pulleys); bounds in
    natural units; ``log`` fits ln(value).
    """

    name: str
    kind: str
    index: int
    refs: tuple[ParamRef, ...]
    scales: tuple[float, ...]
    nominal: float
    lower: float
    upper: float
    log: bool = True
    offsets: tuple[float, ...] = ()

    def to_var(self, value: float) -> float:
        return math.log(value) if self.log else float(value)

    def from_var(self, var: float) -> float:
        return math.exp(var) if self.log else float(var)

    def var_bounds(self) -> tuple[float, float]:
        if self.log:
            return math.log(self.lower), math.log(self.upper)
        return self.lower, self.upper


@dataclass(frozen=True)
class NotIdentified:
    """A parameter left at its nominal value, and why."""

    name: str
    nominal: float
    reason: str


def tilted_gravity(gravity_mm_s2: Sequence[float], tilt_deg: Sequence[float]) -> np.ndarray:
    """The config's gravity vector (base frame, mm/s^2; standard gravity along -z if it is
    zero) turned by the mount tilt ``tilt_deg`` = (about base x, about base y) in degrees:
    g = R(rotvec = (tilt_x, tilt_y, 0)) g_cfg (Rodrigues), size kept. Tilt 0 gives g_cfg."""
    g = np.asarray(gravity_mm_s2, dtype=float)
    if not np.any(g):
        g = np.asarray(STANDARD_GRAVITY_MM_S2, dtype=float)
    a, b = (math.radians(float(t)) for t in tilt_deg)
    return rotation_from_rotvec((a, b, 0.0)) @ g


def apply_values(
    params: RobotParams, fps: Sequence[FitParameter], values: Sequence[float]
) -> RobotParams:
    """``params`` with every fitted parameter set (natural units; tied refs scaled; a mount
    tilt turns ``params``' gravity vector, :func:`tilted_gravity`)."""
    refs: list[ParamRef] = []
    vals: list[float] = []
    tilt = [0.0, 0.0]
    for fp, v in zip(fps, values, strict=True):
        if fp.kind == "gravity_tilt":
            tilt[fp.index] = float(v)
            continue
        offs = fp.offsets or (0.0,) * len(fp.refs)
        for ref, sc, off in zip(fp.refs, fp.scales, offs, strict=True):
            refs.append(ref)
            vals.append(float(v) * sc + off)
    out = with_values(params, refs, vals) if refs else params
    if any(fp.kind == "gravity_tilt" for fp in fps):
        g = tilted_gravity(params.gravity_mm_s2, tilt)
        out = dataclasses.replace(out, gravity_mm_s2=(float(g[0]), float(g[1]), float(g[2])))
    return out


def _pulley_names(params: RobotParams) -> list[str]:
    names: list[str] = []
    for c in params.cables:
        for p in c.pulleys:
            if p.name not in names:
                names.append(p.name)
    return names


def plan_parameters(
    params: RobotParams,
    points: Sequence[DwellPoint],
    locations: Sequence[Location],
    fit_pulleys: str = "auto",
    effects: Effects | None = None,
) -> tuple[list[FitParameter], list[NotIdentified]]:
    """The parameters the dwell data can identify (module docstring) and the ones it cannot.

    ``locations`` per cable: where its load cell sits (the config's). ``fit_pulleys``:
    ``"auto"`` (α always tried, n only with actuator-side cells), ``"on"`` (α and n tried),
    ``"off"``. ``effects``: the controller's model effects (the mount tilt is fitted only
    with gravity on; None: the defaults).
    """
    K = params.n_cables
    pts = list(points)
    has_tip = any(p.has_tip for p in pts)
    has_q = any(np.all(np.isfinite(p.q_act_mm)) for p in pts)
    cell = [any(math.isfinite(float(p.tension_N[k])) for p in pts) for k in range(K)]
    dirs = [{p.s[k] for p in pts} for k in range(K)]
    fit: list[FitParameter] = []
    fixed: list[NotIdentified] = []

    def cable_name(k: int) -> str:
        return params.cables[k].name

    for i, seg in enumerate(params.segments):
        name = f"{seg.name}.EI_Nmm2"
        nom = seg.EI_Nmm2
        own = params.cables_of(i)
        bends = [float(p.psi_cmd[i, 0]) for p in pts]
        if not has_tip:
            fixed.append(NotIdentified(name, nom, "no tracker tip: the bend is not measured"))
        elif not any(cell[k] for k in own):
            fixed.append(
                NotIdentified(name, nom, "no load cell on its cables: only EI/EA would show")
            )
        elif max(bends) - min(bends) < MIN_BEND_RANGE_RAD:
            fixed.append(NotIdentified(name, nom, "the segment was not bent in the sweep"))
        else:
            ref = ParamRef("segment", i, "EI_Nmm2")
            fit.append(FitParameter(name, "EI", i, (ref,), (1.0,), nom, nom / 10, nom * 10))

    for k in range(K):
        name = f"{cable_name(k)}.mu_disk"
        nom = params.cables[k].mu_disk
        if not cell[k]:
            fixed.append(NotIdentified(name, nom, "no load cell on this cable"))
        elif not has_tip:
            fixed.append(NotIdentified(name, nom, "no tracker tip: the wrap angle is unknown"))
        elif not ({1.0, -1.0} <= dirs[k]):
            fixed.append(NotIdentified(name, nom, "the cable did not move both ways"))
        else:
            ref = ParamRef("cable", k, "mu_disk")
            fit.append(FitParameter(name, "mu", k, (ref,), (1.0,), nom, 1e-4, max(2.0, 4 * nom)))

    for k in range(K):
        c = params.cables[k]
        for field, kind, nom in (
            ("EA_N", "EA", c.EA_N),
            ("pretension_N", "pretension", c.pretension_N),
        ):
            name = f"{cable_name(k)}.{field}"
            if not has_q:
                fixed.append(NotIdentified(name, nom, "no drive feedback or command"))
            elif not has_tip:
                fixed.append(
                    NotIdentified(name, nom, "no tracker tip: the geometric length is unknown")
                )
            elif not cell[k]:
                fixed.append(NotIdentified(name, nom, "no load cell on this cable"))
            elif kind == "EA" and not math.isfinite(nom):
                fixed.append(NotIdentified(name, nom, "the config says the cable is rigid"))
            else:
                ref = ParamRef("cable", k, field)
                if kind == "EA":
                    fp = FitParameter(name, kind, k, (ref,), (1.0,), nom, nom / 20, nom * 20)
                else:
                    hi = max(10.0 * nom, 20.0)
                    fp = FitParameter(name, kind, k, (ref,), (1.0,), nom, 0.0, hi, log=False)
                fit.append(fp)

    for k in range(K):
        name = f"{cable_name(k)}.backlash_mm"
        nom = params.cables[k].backlash_mm
        if not has_q:
            fixed.append(NotIdentified(name, nom, "no drive feedback or command"))
        elif not has_tip:
            fixed.append(NotIdentified(name, nom, "no tracker tip: the cable position is unknown"))
        elif not ({1.0, -1.0} <= dirs[k]):
            fixed.append(NotIdentified(name, nom, "the cable did not move both ways"))
        else:
            ref = ParamRef("cable", k, "backlash_mm")
            hi = max(5.0, 4.0 * nom)
            fit.append(FitParameter(name, "backlash", k, (ref,), (1.0,), nom, 0.0, hi, log=False))

    gravity_on = (Effects() if effects is None else effects).gravity
    massive = any(seg.disk_mass_g > 0 for seg in params.segments)
    for axis, label in enumerate(("x", "y")):
        name = f"mount.tilt_{label}_deg"
        if not (gravity_on and massive):
            why = "the model has no gravity load (gravity off or massless disks)"
        elif not has_tip:
            why = "no tracker tip: the pose the weights act at is unknown"
        elif not any(cell):
            why = "no load cell: the moment balance is not measured"
        else:
            fit.append(
                FitParameter(
                    name, "gravity_tilt", axis, (), (), 0.0, -MAX_TILT_DEG, MAX_TILT_DEG, log=False
                )
            )
            continue
        fixed.append(NotIdentified(name, 0.0, why))

    names = _pulley_names(params)
    if names and fit_pulleys != "off":
        first = names[0]
        ref0 = ParamRef("pulley", first, "alpha")
        a0 = get_value(params, ref0)
        n0 = get_value(params, ParamRef("pulley", first, "n"))
        alphas = [get_value(params, ParamRef("pulley", nm, "alpha")) for nm in names]
        ns = [get_value(params, ParamRef("pulley", nm, "n")) for nm in names]
        pulley_cells = [locations[k] for k, c in enumerate(params.cables) if c.pulleys and cell[k]]
        at_actuator = any(loc == "actuator" for loc in pulley_cells)
        if not pulley_cells:
            fixed.append(NotIdentified("pulleys.alpha", a0, "no load cell on a cable with pulleys"))
        elif not has_tip or not has_q:
            fixed.append(NotIdentified("pulleys.alpha", a0, "needs the tip and drive feedback"))
        elif a0 <= 0.0:
            fixed.append(NotIdentified("pulleys.alpha", a0, "nominal alpha is 0 (frictionless)"))
        else:
            refs = tuple(ParamRef("pulley", nm, "alpha") for nm in names)
            fit.append(
                FitParameter(
                    "pulleys.alpha",
                    "pulley_alpha",
                    -1,
                    refs,
                    tuple(a / a0 for a in alphas),
                    a0,
                    a0 / 20,
                    min(2.0, 20 * a0),
                )
            )
        if at_actuator or fit_pulleys == "on":
            if len(set(ns)) > 1:
                fixed.append(NotIdentified("pulleys.n", n0, "pulleys have different nominal n"))
            elif has_tip and has_q and pulley_cells:
                refs = tuple(ParamRef("pulley", nm, "n") for nm in names)
                fit.append(
                    FitParameter(
                        "pulleys.n",
                        "pulley_n",
                        -1,
                        refs,
                        (1.0,) * len(names),
                        n0,
                        0.3,
                        1.0,
                        log=False,
                    )
                )
        else:
            fixed.append(
                NotIdentified(
                    "pulleys.n",
                    n0,
                    "load cells at the robot base: the pulley tension ratio is not measured",
                )
            )
    elif names:
        fixed.append(
            NotIdentified(
                "pulleys.alpha",
                get_value(params, ParamRef("pulley", names[0], "alpha")),
                "pulley fit switched off",
            )
        )
    order = {k: j for j, k in enumerate(KINDS)}
    fit.sort(key=lambda f: (order[f.kind], f.index))
    return fit, fixed
