"""Identification from tip-only and keypoint logs (issue 18): observability, fit, held-out check.

The lab logs this serves hold actuator positions and a tracked tip (sometimes load cells), with
rows seconds apart and no commanded pose (:mod:`.logkind`). The model is the forward replay of
the logged actuator path (:mod:`.replay_fit`: an output-error fit; the friction memory, stick
after reversals and slack cables come out of the replay, as on the rig), over the candidate
parameters of :func:`candidates`:

* EI per segment;
* EA, pretension, disk friction mu and routing radius, each one scale shared by every cable
  (the nominal spread between cables kept): tip-only data cannot split them per cable;
* a hole-angle offset per segment (rad, added to every hole of the segment).

Steps (:func:`identify_keypoint_runs`):

1. points per run; split by time: the last ``holdout`` fraction of each run is never fitted;
   of the rest the first ``max_points`` rows of each run are fitted (a prefix, so every replay
   starts where the run started);
2. observability at the config's values (:mod:`.observability`): the replay's weighted
   sensitivity to every candidate, its singular values, a 95 % half-width per candidate; the
   ones not identifiable stay at the config, with the reason;
3. the fit of the identifiable ones (:func:`.replay_fit.fit`), reduced chi^2 and 95 % intervals
   from its Jacobian (widened by sqrt(chi^2) when the residual exceeds the noise);
4. held-out check: the forward replay of every row of the run with the config's and the fitted
   parameters; tip RMSE over the held-out rows (and, for reference, the other rows). Rows with
   no static solution are named and left out of the RMSE.
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
from cdcr_ctl.identify import replay_fit
from cdcr_ctl.identify.dwell import DwellPoint, extract_dwells
from cdcr_ctl.identify.fit_types import Identification
from cdcr_ctl.identify.logkind import detect_kind, keypoint_points, split_by_time
from cdcr_ctl.identify.observability import Observability, select, tolerance
from cdcr_ctl.identify.parameters import FitParameter, NotIdentified
from cdcr_ctl.identify.replay_fit import Evaluator, ReplayProblem, RunRows
from cdcr_ctl.model.forward import ForwardStepper, replay
from cdcr_ctl.model.identification import ParamRef
from cdcr_ctl.model.params import Effects, RobotParams
from cdcr_ctl.runlog.reader import load_run

#: Fraction of each run's time span held out (the end of the run).
HOLDOUT_FRACTION = 0.3
#: Most rows fitted per run: the first ones by time (every replay starts at the run's start).
MAX_FIT_POINTS = 150
#: Tracker noise assumed for a single keypoint row (mm, per axis).
TIP_NOISE_MM = 0.05
#: Load-cell noise assumed for a single keypoint row (N).
TENSION_NOISE_N = 0.02
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
    max_nfev: int = 30  # least-squares iterations (each costs one replay per fitted parameter)
    tension_noise_N: float = TENSION_NOISE_N
    jobs: int | None = None  # worker processes for the Jacobian's replays (None: CPU count)
    backlash: bool = False  # also the candidate cables.backlash_mm (:func:`candidates`)


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


def candidates(params: RobotParams, backlash: bool = False) -> list[FitParameter]:
    """The candidate parameters of a tip/keypoint log (module docstring), nominal = config;
    ``backlash``: also one lost motion (play, mm) added to every cable's config value (Yang et
    al. 2022 eq. 13-17, the play operator between drive and cable; the effect ``discrepancy``
    looks for on keypoint logs)."""
    out: list[FitParameter] = []
    cab = params.cables
    if backlash:
        refs = tuple(ParamRef("cable", k, "backlash_mm") for k in range(len(cab)))
        offs = tuple(c.backlash_mm for c in cab)
        out.append(
            FitParameter(
                "cables.backlash_mm",
                "backlash",
                -1,
                refs,
                (1.0,) * len(cab),
                0.0,
                0.0,
                3.0,
                log=False,
                offsets=offs,
            )
        )
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
        rep = replay(ForwardStepper(params, replay_fit.effects_of(params, effects)), rdat.q_path)
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
    locs = tuple(loadcell_locations(cfg))
    runs, kinds, warnings = _load(run_dirs, opt.kind, params.n_segments)
    points = [p for r in runs for p in r.points]
    if not points:
        raise RigError("identification: the runs hold no row with a tip")
    fit_all, held_pts = split_by_time(points, opt.holdout)
    fit_keys = {(p.run, p.index) for p in fit_all}
    rr = [_run_rows(r, fit_keys, opt.max_points) for r in runs]
    rr = [r for r in rr if r is not None]
    n_fit = sum(len(r.rows) for r in rr)
    if n_fit < 10:
        raise RigError(f"identification: only {n_fit} rows to fit from")
    prob = ReplayProblem(params, effects, tuple(rr), locs, opt.tip_noise_mm, opt.tension_noise_N)
    fps = candidates(params, opt.backlash)
    scales = [tolerance(fp, opt.max_rel, opt.max_offset_rad) for fp in fps]
    held_keys = {(p.run, p.index) for p in held_pts}
    with Evaluator(prob, opt.jobs) as ev:
        # observability: the replay's sensitivity to every candidate at the config's values
        x0 = np.array([fp.to_var(fp.nominal) for fp in fps])
        hi = np.array([fp.var_bounds()[1] for fp in fps])
        r0 = ev.map_params([params])[0]
        J = ev.jacobian(fps, x0, r0, hi)
        keep, dropped, obs = select(J, fps, scales)
        fixed = [NotIdentified(fps[i].name, fps[i].nominal, why) for i, why in dropped]
        if not keep:
            raise RigError(
                "identification: nothing identifiable in these runs: "
                + "; ".join(f"{f.name}: {f.reason}" for f in fixed)
            )
        kfps = [fps[i] for i in keep]
        sol = replay_fit.fit(ev, kfps, [scales[i] for i in keep], opt.max_nfev, (r0, J[:, keep]))
        fitted = prob.params_of(kfps, sol.x)
        (h_nom, f_nom, _), (h_fit, f_fit, failed) = _heldout_both(
            ev, (params, fitted), effects, runs, held_keys
        )
    ident = _identification(
        prob, params, fitted, sol, fixed, [p for p in points if (p.run, p.index) in fit_keys]
    )
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
        n_fit,
        time.monotonic() - t0,
        warnings,
        opt.holdout,
    )


def _run_rows(r: _RunData, fit_keys: set, max_rows: int) -> RunRows | None:
    """The first ``max_rows`` fitted rows of a run (by time) and its path up to the last."""
    idx = [j for j, p in enumerate(r.points) if (p.run, p.index) in fit_keys][:max_rows]
    if not idx:
        return None
    rows = np.array([r.rows[j] for j in idx], dtype=int)
    return RunRows(
        r.name,
        r.q_path[: int(rows.max()) + 1],
        rows,
        np.array([r.points[j].tip_mm for j in idx]),
        np.array([r.points[j].tension_N for j in idx]),
    )


def _heldout_task(args: tuple) -> tuple[float, float, list[str]]:
    return heldout_rmse(*args)


def _heldout_both(ev: Evaluator, plist, effects, runs, held_keys) -> list:
    """:func:`heldout_rmse` for each parameter set, in the evaluator's workers."""
    tasks = [(p, effects, runs, held_keys) for p in plist]
    ev.n_replays += len(tasks)
    if ev.pool is None:
        return [_heldout_task(t) for t in tasks]
    return list(ev.pool.map(_heldout_task, tasks))


def _identification(
    prob: ReplayProblem,
    nominal: RobotParams,
    fitted: RobotParams,
    sol: replay_fit.ReplayFit,
    fixed: list[NotIdentified],
    points: list[DwellPoint],
) -> Identification:
    warnings = [
        f"{e.name}: fitted value {e.value:.4g} is on its bound" for e in sol.estimates if e.at_bound
    ]
    if sol.s2 > 1.0:
        warnings.append(
            f"reduced chi^2 {sol.chi2_reduced:.3g} > 1: the residual exceeds the assumed noise; "
            f"the 95 % intervals are widened by sqrt(chi^2) = {math.sqrt(sol.s2):.3g}"
        )

    def per_kind(res: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        t = res[sol.is_tip].reshape(-1, 3) * prob.tip_noise_mm
        c = res[~sol.is_tip] * prob.tension_noise_N
        return {
            "tip": (np.arange(len(t)), np.linalg.norm(t, axis=1)),
            "cell": (np.arange(c.size), c),
        }

    S = nominal.n_segments
    return Identification(
        nominal=nominal,
        fitted=fitted,
        estimates=sol.estimates,
        fixed=fixed,
        points=points,
        rms_before=replay_fit.rms_by_kind(sol.res_before, sol.is_tip, prob),
        rms_after=replay_fit.rms_by_kind(sol.res_after, sol.is_tip, prob),
        residuals_before=per_kind(sol.res_before),
        residuals_after=per_kind(sol.res_after),
        poses=np.zeros((0, 2 * S)),
        s=np.zeros((0, nominal.n_cables)),
        chi2_reduced=sol.chi2_reduced,
        n_residuals=sol.n_residuals,
        n_unknowns=len(sol.estimates),
        stages=[f"output-error fit over the forward replay: {sol.nfev} evaluations, {sol.message}"],
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
