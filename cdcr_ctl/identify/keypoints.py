"""Identification from tip-only and keypoint logs (issue 18): observability, fit, held-out check.

The lab logs this serves hold actuator positions and a tracked tip (sometimes load cells), with
rows seconds apart and no commanded pose (:mod:`.logkind`). The fit is the errors-in-variables
problem of :mod:`.estimator` (every row's pose and anchor tensions are nuisance unknowns; tip,
moment balance and cable compatibility residuals, with compatibility written slack-aware:
:attr:`FitOptions.slack_compat`), over the candidate parameters of :func:`candidates`:

* EI per segment (moment balance against the cable tensions the compatibility implies);
* EA, pretension, disk friction mu and routing radius, each one scale shared by every cable
  (the nominal spread between cables kept): tip-only data cannot split them per cable;
* a hole-angle offset per segment (rad, added to every hole of the segment).

Steps (:func:`identify_keypoint_runs`):

1. points per run; split by time: the last ``holdout`` fraction of each run is never fitted;
   the fitted part is thinned to ``max_points`` rows evenly spread (friction directions are
   taken from the full path first);
2. observability at the nominal parameters (:mod:`.observability`): the sensitivity matrix with
   the poses and tensions projected out, its singular values, a 95 % half-width per candidate;
   the ones not identifiable stay at the config, with the reason;
3. the fit of the identifiable ones (:func:`~.estimator.identify`), reduced chi^2 and 95 %
   intervals from its Jacobian;
4. held-out check: the forward model (:func:`cdcr_ctl.model.forward.replay`, friction memory
   kept over every row of the run) with the nominal and the fitted parameters; tip RMSE over
   the held-out rows (and, for reference, the fitted rows). Rows with no static solution are
   named and left out of the RMSE.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cdcr_ctl.config.build_model import build_model, loadcell_locations
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import ConfigError, RigError
from cdcr_ctl.identify.dwell import DwellPoint, extract_dwells
from cdcr_ctl.identify.estimator import (
    RESIDUAL_KINDS,
    FitOptions,
    Identification,
    _estimates,
    _Problem,
    initial_nuisance,
)
from cdcr_ctl.identify.logkind import detect_kind, keypoint_points, split_by_time, thin
from cdcr_ctl.identify.observability import Observability, schur_sensitivity, select, tolerance
from cdcr_ctl.identify.parameters import FitParameter, NotIdentified
from cdcr_ctl.model.forward import ForwardStepper, replay
from cdcr_ctl.model.identification import ParamRef
from cdcr_ctl.model.params import Effects, RobotParams
from cdcr_ctl.runlog import load_run

#: Fraction of each run's time span held out (the end of the run).
HOLDOUT_FRACTION = 0.3
#: Most rows fitted (evenly spread over the fitted part of the runs).
MAX_FIT_POINTS = 60
#: Tracker noise assumed for a single keypoint row (mm, per axis).
TIP_NOISE_MM = 0.05
#: Tolerances of observability: relative for positive parameters, absolute for hole offsets.
MAX_REL = 0.25
MAX_OFFSET_RAD = math.radians(1.0)


@dataclass(frozen=True)
class KeypointOptions:
    """Settings of :func:`identify_keypoint_runs` (module docstring)."""

    holdout: float = HOLDOUT_FRACTION
    max_points: int = MAX_FIT_POINTS
    tip_noise_mm: float = TIP_NOISE_MM
    max_rel: float = MAX_REL
    max_offset_rad: float = MAX_OFFSET_RAD
    kind: str | None = None  # None: detect per run
    max_nfev: int = 20  # least-squares evaluations per stage (each costs one Jacobian)


@dataclass
class HeldOut:
    """Forward-model tip RMSE (mm) over held-out and fitted rows, and rows with no solution."""

    rmse_nominal: float
    rmse_fitted: float
    rmse_fit_rows_nominal: float
    rmse_fit_rows_fitted: float
    n_rows: int
    failed: list[str] = field(default_factory=list)


@dataclass
class KeypointIdentification:
    kinds: dict[str, str]
    ident: Identification
    observability: Observability
    heldout: HeldOut
    n_points: int
    n_fit: int
    fit_time_s: float
    warnings: list[str]
    holdout: float = HOLDOUT_FRACTION


def candidates(params: RobotParams) -> list[FitParameter]:
    """The candidate parameters of a tip/keypoint log (module docstring), nominal = config."""
    out: list[FitParameter] = []
    cab = params.cables
    for i, seg in enumerate(params.segments):
        nom = seg.EI_Nmm2
        ref = ParamRef("segment", i, "EI_Nmm2")
        out.append(
            FitParameter(f"{seg.name}.EI_Nmm2", "EI", i, (ref,), (1.0,), nom, nom / 10, nom * 10)
        )

    def shared(field_: str, kind: str, lo: float, hi: float) -> None:
        vals = [float(getattr(c, field_)) for c in cab]
        v0 = vals[0]
        if not (v0 > 0 and all(math.isfinite(v) and v > 0 for v in vals)):
            return
        refs = tuple(ParamRef("cable", k, field_) for k in range(len(cab)))
        scales = tuple(v / v0 for v in vals)
        out.append(FitParameter(f"cables.{field_}", kind, -1, refs, scales, v0, v0 * lo, v0 * hi))

    shared("EA_N", "EA", 1 / 20, 20.0)
    shared("pretension_N", "pretension", 1 / 20, 20.0)
    shared("mu_disk", "mu", 1 / 50, 10.0)
    shared("routing_radius_mm", "routing_radius", 0.5, 2.0)
    for i, seg in enumerate(params.segments):
        ks = params.cables_of(i)
        refs = tuple(ParamRef("cable", k, "hole_angle_rad") for k in ks)
        out.append(
            FitParameter(
                f"{seg.name}.hole_offset_rad",
                "hole_offset",
                i,
                refs,
                (1.0,) * len(ks),
                0.0,
                -0.35,
                0.35,
                log=False,
                offsets=tuple(cab[k].hole_angle_rad for k in ks),
            )
        )
    return out


@dataclass
class _RunData:
    name: str
    q_path: np.ndarray  # (N, K) mm: what the forward replay steps through
    points: list[DwellPoint]
    rows: list[int]  # row of q_path of each point


def _load(
    run_dirs: Sequence[str | Path], forced: str | None, n_segments: int
) -> tuple[list[_RunData], dict, list]:
    runs: list[_RunData] = []
    kinds: dict[str, str] = {}
    warnings: list[str] = []
    for rd in run_dirs:
        run = load_run(rd)
        warnings += run.warnings
        kind, why = (forced, "given by --log-kind") if forced else detect_kind(run)
        kinds[str(rd)] = f"{kind}: {why}"
        if kind == "keypoint":
            pts, q, w = keypoint_points(run, n_segments)
            rows = [p.index for p in pts]
        else:
            dwells, w = extract_dwells(run)
            q = np.array([p.q_act_mm for p in dwells])  # the replay steps dwell to dwell
            rows = [r for r, p in enumerate(dwells) if p.has_tip]
            pts = [dwells[r] for r in rows]
        warnings += w
        runs.append(_RunData(run.run_dir.name, q, pts, rows))
    return runs, kinds, warnings


def heldout_rmse(
    params: RobotParams,
    effects: Effects,
    runs: Sequence[Any],
    held: set[tuple[str, int]],
) -> tuple[float, float, list[str]]:
    """Tip RMSE (mm) of the forward replay over held-out and over other point rows."""
    e_held: list[float] = []
    e_fit: list[float] = []
    failed: list[str] = []
    for rdat in runs:
        rep = replay(ForwardStepper(params, effects), rdat.q_path)
        failed += [f"{rdat.name} row {i}: {why}" for i, why in rep.failed]
        for p, row in zip(rdat.points, rdat.rows, strict=True):
            d = rep.tip_mm[row] - p.tip_mm
            if not np.all(np.isfinite(d)):
                continue
            (e_held if (p.run, p.index) in held else e_fit).append(float(d @ d))
    rms = [math.sqrt(sum(e) / len(e)) if e else math.nan for e in (e_held, e_fit)]
    return rms[0], rms[1], failed


def identify_keypoint_runs(
    cfg: RigConfig,
    run_dirs: Sequence[str | Path],
    options: KeypointOptions | None = None,
) -> KeypointIdentification:
    """Observability, fit and held-out check of a tip-only or keypoint log (module docstring)."""
    opt = KeypointOptions() if options is None else options
    if cfg.design != "cc_disk":
        raise ConfigError(
            "rig config", "design", "identification fits the cc_disk model (Qi 2023)", cfg.design
        )
    t0 = time.monotonic()
    model = build_model(cfg)
    params, effects = model.params, model.effects
    locs = loadcell_locations(cfg)
    runs, kinds, warnings = _load(run_dirs, opt.kind, params.n_segments)
    points = [p for r in runs for p in r.points]
    if not points:
        raise RigError("identification: the runs hold no row with a tip")
    fit_all, held_pts = split_by_time(points, opt.holdout)
    fit_pts = thin(fit_all, opt.max_points)
    if len(fit_pts) < 10:
        raise RigError(f"identification: only {len(fit_pts)} rows to fit from")
    fopt = FitOptions(tip_floor_mm=opt.tip_noise_mm, slack_compat=True, max_nfev=opt.max_nfev)
    fps = candidates(params)
    # observability at the nominal parameters, poses and tensions fitted
    prob = _Problem(params, effects, fit_pts, locs, fps, fopt)
    nuis = initial_nuisance(params, effects, fit_pts, locs, prob.unc)
    prob.set_stage([], RESIDUAL_KINDS)
    nuis, _ = prob.solve(nuis, fopt.max_nfev)
    prob.set_stage(list(range(len(fps))), RESIDUAL_KINDS)
    lo, hi = prob.bounds()
    z = prob.pack(nuis)
    J = prob.jacobian(z, lo, hi)
    J_eff = schur_sensitivity(J, len(fps), prob.row_off, prob.offsets)
    scales = [tolerance(fp, opt.max_rel, opt.max_offset_rad) for fp in fps]
    keep, dropped, obs = select(J_eff, fps, scales)
    fixed = [NotIdentified(fps[i].name, fps[i].nominal, why) for i, why in dropped]
    if not keep:
        raise RigError(
            "identification: nothing identifiable in these runs: "
            + "; ".join(f"{f.name}: {f.reason}" for f in fixed)
        )
    ident = _fit(prob, nuis, [fps[i] for i in keep], fixed, fopt)
    held_keys = {(p.run, p.index) for p in held_pts}
    h_nom, f_nom, _ = heldout_rmse(params, effects, runs, held_keys)
    h_fit, f_fit, failed = heldout_rmse(ident.fitted, effects, runs, held_keys)
    heldout = HeldOut(h_nom, h_fit, f_nom, f_fit, len(held_pts), failed)
    if failed:
        warnings.append(f"{len(failed)} rows with no static solution (left out of the RMSE)")
    if not h_fit <= h_nom:
        warnings.append(
            f"the fitted model predicts the held-out rows worse than the config "
            f"({h_fit:.4g} vs {h_nom:.4g} mm): the fit does not explain this log"
        )
    ident.warnings[:0] = warnings
    return KeypointIdentification(
        kinds,
        ident,
        obs,
        heldout,
        len(points),
        len(fit_pts),
        time.monotonic() - t0,
        warnings,
        opt.holdout,
    )


def _fit(
    prob0: _Problem,
    nuis: np.ndarray,
    fps: list[FitParameter],
    fixed: list[NotIdentified],
    fopt: FitOptions,
) -> Identification:
    """Joint fit of ``fps`` from the nuisance of the observability step (one stage: the
    poses and tensions are already fitted at the nominal parameters)."""
    prob = _Problem(prob0.base, prob0.effects, prob0.points, prob0.locations, fps, fopt)
    prob.set_stage(list(range(len(fps))), RESIDUAL_KINDS)
    before = prob.kind_residuals(prob.pack(nuis))
    nuis, sol = prob.solve(nuis, fopt.max_nfev)
    estimates, chi2, m, n = _estimates(prob, sol.x)
    after = prob.kind_residuals(sol.x)
    S = prob.S
    poses = np.array(
        [nuis[prob.offsets[j] : prob.offsets[j] + 2 * S] for j in range(len(prob.points))]
    )
    s_fit = np.array(
        [
            prob.split_block(j, nuis[prob.offsets[j] : prob.offsets[j + 1]])[2]
            for j in range(len(prob.points))
        ]
    )
    warnings = [
        f"{e.name}: fitted value {e.value:.4g} is on its bound" for e in estimates if e.at_bound
    ]

    def rms(res: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
        return {
            k: float(np.sqrt(np.mean(v**2))) if v.size else math.nan for k, (_, v) in res.items()
        }

    return Identification(
        nominal=prob0.base,
        fitted=prob.params_of(prob.g_all),
        estimates=estimates,
        fixed=fixed,
        points=prob.points,
        rms_before=rms(before),
        rms_after=rms(after),
        residuals_before=before,
        residuals_after=after,
        poses=poses,
        s=s_fit,
        chi2_reduced=chi2,
        n_residuals=m,
        n_unknowns=n,
        stages=[f"joint fit: cost {sol.cost:.4g}, {sol.nfev} evaluations, {sol.message}"],
        warnings=warnings,
    )


def report_lines(res: KeypointIdentification) -> list[str]:
    """Plain-text report: kinds, what was fitted and fixed (why), chi2, held-out residual."""
    from cdcr_ctl.identify.pipeline import summary_table

    out = [f"log kind: {k}" for k in res.kinds.values()]
    out.append(
        f"{res.n_points} rows with a tip; {res.n_fit} fitted (first "
        f"{100 * (1 - res.holdout):.0f} % of each run by time, thinned), "
        f"{res.heldout.n_rows} held out"
    )
    out += res.observability.lines()
    out.append("identifiable and fitted: " + ", ".join(e.name for e in res.ident.estimates))
    out.append("fixed at the config: " + (", ".join(f.name for f in res.ident.fixed) or "none"))
    out.append(summary_table(res.ident))
    h = res.heldout
    out.append(
        f"reduced chi^2 {res.ident.chi2_reduced:.4g} over {res.ident.n_residuals} residuals "
        f"(residuals weighted by the assumed noise)"
    )
    out.append(
        f"held-out tip RMSE (forward model, {h.n_rows} rows never fitted): "
        f"config {h.rmse_nominal:.4g} mm -> fitted {h.rmse_fitted:.4g} mm"
    )
    out.append(
        f"fitted rows' tip RMSE (forward model): config {h.rmse_fit_rows_nominal:.4g} mm -> "
        f"fitted {h.rmse_fit_rows_fitted:.4g} mm"
    )
    out.append(f"rows with no static solution: {len(h.failed)}")
    out += [f"  {f}" for f in h.failed[:20]]
    return out
