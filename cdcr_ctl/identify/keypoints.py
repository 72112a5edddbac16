"""Identification from tip-only and keypoint logs: rows that span the log, fit, held-out gate.

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
2. the config's replay of every row (the held-out baseline; it also measures what one replayed
   row costs on this machine); the tracker noise from the log (:mod:`.keypoint_gate`);
3. rows to fit: as many as the budget ``budget_s`` allows (all of them when it allows),
   chosen to span the actuator space and the friction states (:mod:`.rowselect`,
   farthest-point), each replayed after the row before it. The budget is CPU time of the
   replays (the config's replay measures a row's cost), not wall time: a loaded machine fits
   about the same rows (a row's CPU cost varies ~20 % with the load) and takes longer;
4. observability at the config's values (:mod:`.observability`): the replay's weighted
   sensitivity to every candidate, its singular values, a 95 % half-width per candidate; the
   ones not identifiable stay at the config, with the reason;
5. the fit of the identifiable ones (:func:`.replay_fit.fit`, stopped at the CPU budget with
   the best point kept), reduced chi^2 and 95 % intervals from its Jacobian (widened by
   sqrt(chi^2) when the residual exceeds the noise, clipped to the bounds and then said so);
6. held-out check and gate (:mod:`.keypoint_gate`): the replay of every row with the fitted
   parameters; tip RMSE over the held-out rows, whether they improved beyond their noise, and
   the misfit ratio. Rows with no static solution are named and left out of the RMSE.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cdcr_ctl.config.build_model import build_model, friction_law, loadcell_locations
from cdcr_ctl.config.registry import design_of
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import ConfigError, RigError
from cdcr_ctl.identify import replay_fit
from cdcr_ctl.identify.dwell import DwellPoint, extract_dwells
from cdcr_ctl.identify.fit_types import Identification
from cdcr_ctl.identify.heldout import _errors_both, _rms, _split_errors
from cdcr_ctl.identify.keypoint_gate import KeypointVerdict, heldout_gain, tracker_noise
from cdcr_ctl.identify.logkind import detect_kind, keypoint_points, split_by_time
from cdcr_ctl.identify.observability import Observability, select, tolerance
from cdcr_ctl.identify.parameters import FitParameter, NotIdentified
from cdcr_ctl.identify.replay_fit import Evaluator, ReplayProblem, RunRows
from cdcr_ctl.identify.rowselect import (
    Spread,
    farthest_points,
    features,
    replay_path,
    rows_for_budget,
    spread,
)
from cdcr_ctl.model.cc_disk.identification import ParamRef
from cdcr_ctl.model.cc_disk.params import RobotParams
from cdcr_ctl.runlog.reader import load_run

#: Fraction of each run's time span held out (the end of the run).
HOLDOUT_FRACTION = 0.3
#: CPU time (s) the replays of the fit of the chosen rows may take, the observability Jacobian
#: included (the two whole-log replays come on top).
BUDGET_S = 20.0
#: Jacobians a fit is planned for (the observability one and the least-squares iterations).
FIT_ITERATIONS = 6
#: Tracker noise assumed when the log gives no estimate (mm, per axis).
TIP_NOISE_MM = 0.05
#: Load-cell noise assumed for a single keypoint row (N).
TENSION_NOISE_N = 0.02
#: Tolerances of observability: relative for positive parameters, absolute for hole offsets.
MAX_REL = 0.25
MAX_OFFSET_RAD = math.radians(1.0)


@dataclass(frozen=True)
class KeypointOptions:
    """Settings of :func:`identify_keypoint_runs` (module docstring).

    ``max_points``: rows fitted in all (None: as many as ``budget_s`` allows, chosen to span
    the log); ``tip_noise_mm``: tracker noise per axis (None: estimated from the log);
    ``progress``: called with a line at every step and evaluation (None: quiet)."""

    holdout: float = HOLDOUT_FRACTION
    max_points: int | None = None
    tip_noise_mm: float | None = None
    max_rel: float = MAX_REL
    max_offset_rad: float = MAX_OFFSET_RAD
    kind: str | None = None  # None: detect per run
    max_nfev: int = 30  # least-squares trial evaluations (the Jacobians not counted)
    tension_noise_N: float = TENSION_NOISE_N
    jobs: int | None = None  # worker processes for the Jacobian's replays (None: CPU count)
    backlash: bool = False  # also the candidate cables.backlash_mm (:func:`candidates`)
    budget_s: float = BUDGET_S
    progress: Callable[[str], None] | None = None
    obs_at_residual: bool = False  # True: observability with the noise widened to the residual


@dataclass
class HeldOut:
    """Forward-model tip RMSE (mm) over held-out rows and over the rows before the hold-out
    cut (fitted or not), and rows with no solution."""

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
    verdict: KeypointVerdict | None = None
    spreads: list[Spread] = field(default_factory=list)
    n_candidates: int = 0
    rows_why: str = ""
    tip_noise_mm: float = TIP_NOISE_MM
    candidates: list[FitParameter] = field(default_factory=list)


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


def identify_keypoint_runs(
    cfg: RigConfig,
    run_dirs: Sequence[str | Path],
    options: KeypointOptions | None = None,
) -> KeypointIdentification:
    """Observability, fit and held-out check of a tip-only or keypoint log (module docstring)."""
    opt = KeypointOptions() if options is None else options
    if not design_of(cfg.design).identify:
        raise ConfigError(
            "rig config",
            "design",
            "identification fits a design registered with identify=True (cc_disk, Qi 2023)",
            cfg.design,
        )
    t0 = time.monotonic()
    say = opt.progress or (lambda _line: None)
    model = build_model(cfg)
    params, effects = model.params, model.effects
    locs, law = tuple(loadcell_locations(cfg)), friction_law(cfg.robot)
    runs, kinds, warnings = _load(run_dirs, opt.kind, params.n_segments)
    points = [p for r in runs for p in r.points]
    if not points:
        raise RigError("identification: the runs hold no row with a tip")
    fit_all, held_pts = split_by_time(points, opt.holdout)
    fit_keys = {(p.run, p.index) for p in fit_all}
    held_keys = {(p.run, p.index) for p in held_pts}
    noise, n_tri = _noise(runs)
    tip_noise = opt.tip_noise_mm if opt.tip_noise_mm is not None else max(noise, 0.01)
    if not math.isfinite(tip_noise):
        tip_noise = TIP_NOISE_MM
        warnings.append(f"no row triples to estimate the tracker noise; assumed {TIP_NOISE_MM} mm")
    fps = candidates(params, opt.backlash)
    scales = [tolerance(fp, opt.max_rel, opt.max_offset_rad) for fp in fps]
    jobs = max(1, min(opt.jobs or (os.cpu_count() or 1), 8))
    with Evaluator(
        ReplayProblem(params, effects, (), locs, tip_noise, opt.tension_noise_N, law), jobs
    ) as ev:
        # the config's replay of every row: held-out baseline and the cost of one row
        (err_nom, _failed) = _errors_both(ev, [params], effects, runs)[0]
        s_row = ev.cpu_s / max(sum(len(r.q_path) for r in runs), 1)
        cpu_mark = ev.cpu_s
        say(
            f"config replay of {sum(len(r.q_path) for r in runs)} rows: "
            f"{s_row * 1e3:.2g} ms CPU per row"
        )
        n_cand = sum(1 for r in runs for p in r.points if (p.run, p.index) in fit_keys)
        if opt.max_points is not None:
            n_want = opt.max_points
            why = f"--max-points {opt.max_points}"
        else:
            cells = any(np.isfinite(p.tension_N).any() for p in points)
            sens = replay_fit.analytic_jacobian(params, fps, cells, law)
            plan = replay_fit.planned_replays(len(fps), sens, FIT_ITERATIONS)
            n_want = rows_for_budget(opt.budget_s, s_row, plan)
            why = (
                f"CPU budget {opt.budget_s:g} s at {s_row * 1e3:.2g} ms CPU per replayed row, "
                f"{len(fps)} candidates, "
                + ("sensitivity replays" if sens else f"forward differences in {jobs} processes")
            )
        rr, spreads = _choose_rows(runs, fit_keys, n_want, n_cand)
        n_fit = sum(len(r.rows) for r in rr)
        if n_fit < 10:
            raise RigError(f"identification: only {n_fit} rows to fit from")
        say(f"fitting {n_fit} of {n_cand} rows ({why})")
        prob = ReplayProblem(params, effects, tuple(rr), locs, tip_noise, opt.tension_noise_N, law)
        ev.set_problem(prob)
        # observability: the replay's sensitivity to every candidate at the config's values
        x0 = np.array([fp.to_var(fp.nominal) for fp in fps])
        hi = np.array([fp.var_bounds()[1] for fp in fps])
        r0 = ev.map_params([params])[0]
        J = ev.jacobian(fps, x0, r0, hi)
        s2_obs = max(1.0, float(r0 @ r0) / max(r0.size, 1)) if opt.obs_at_residual else 1.0
        keep, dropped, obs = select(J, fps, scales, s2_obs)
        fixed = [NotIdentified(fps[i].name, fps[i].nominal, why) for i, why in dropped]
        if not keep:
            raise RigError(
                "identification: nothing identifiable in these runs: "
                + "; ".join(f"{f.name}: {f.reason}" for f in fixed)
            )
        kfps = [fps[i] for i in keep]
        cpu_left = opt.budget_s - (ev.cpu_s - cpu_mark)
        if opt.max_points is not None:
            cpu_left = math.inf
        sol = replay_fit.fit(
            ev,
            kfps,
            [scales[i] for i in keep],
            opt.max_nfev,
            (r0, J[:, keep]),
            progress=say,
            cpu_budget_s=cpu_left,
        )
        fitted = prob.params_of(kfps, sol.x)
        say("held-out check: replay of every row with the fitted parameters")
        (err_fit, failed) = _errors_both(ev, [fitted], effects, runs)[0]
    h_nom, o_nom = _split_errors(runs, err_nom, held_keys)
    h_fit, o_fit = _split_errors(runs, err_fit, held_keys)
    fit_pts = [p for r in runs for p in r.points if (p.run, p.index) in fit_keys]
    ident = _identification(prob, params, fitted, sol, fixed, fit_pts)
    heldout = HeldOut(_rms(h_nom), _rms(h_fit), _rms(o_nom), _rms(o_fit), len(held_pts), failed)
    gain, gain_se = heldout_gain(h_nom, h_fit)
    res_mm = ident.rms_after.get("tip", math.nan) / math.sqrt(3.0)
    verdict = KeypointVerdict(
        noise,
        n_tri,
        res_mm,
        res_mm / noise if noise > 0 else math.nan,
        gain,
        gain_se,
        heldout.rmse_nominal,
        heldout.rmse_fitted,
    )
    if failed:
        warnings.append(f"{len(failed)} rows with no static solution (left out of the RMSE)")
    if verdict.misfit:
        warnings.append(verdict.lines()[2])
    if not verdict.improved:
        warnings.append(
            f"the fitted model does not predict the held-out rows better beyond their noise "
            f"({heldout.rmse_nominal:.4g} -> {heldout.rmse_fitted:.4g} mm): the fit does not "
            "explain this log"
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
        ident.warnings,
        opt.holdout,
        verdict=verdict,
        spreads=spreads,
        n_candidates=n_cand,
        rows_why=why,
        tip_noise_mm=tip_noise,
        candidates=fps,
    )


def _noise(runs: Sequence[_RunData]) -> tuple[float, int]:
    """Tracker noise per axis from the log (:func:`.keypoint_gate.tracker_noise`), pooled."""
    vals: list[tuple[float, int]] = []
    for r in runs:
        tips = np.full((len(r.q_path), 3), np.nan)
        tips[np.asarray(r.rows, dtype=int)] = [p.tip_mm for p in r.points]
        vals.append(tracker_noise(r.q_path, tips))
    n = sum(k for _, k in vals)
    ok = [(s, k) for s, k in vals if k > 0 and math.isfinite(s)]
    if not ok:
        return math.nan, n
    return math.sqrt(sum(s * s * k for s, k in ok) / sum(k for _, k in ok)), n


def _choose_rows(
    runs: Sequence[_RunData], fit_keys: set, n_want: int, n_cand: int
) -> tuple[list[RunRows], list[Spread]]:
    """Per run its share of ``n_want`` rows, chosen to span it (:mod:`.rowselect`)."""
    out: list[RunRows] = []
    spreads: list[Spread] = []
    for r in runs:
        idx = np.array([j for j, p in enumerate(r.points) if (p.run, p.index) in fit_keys])
        if idx.size == 0:
            continue
        share = max(1, round(n_want * idx.size / max(n_cand, 1)))
        cand_rows = np.asarray(r.rows, dtype=int)[idx]
        f, _ = features(r.q_path, cand_rows)
        pick = farthest_points(f, share)
        spreads.append(spread(r.q_path, cand_rows, pick))
        chosen = idx[pick]
        rows = np.asarray(r.rows, dtype=int)[chosen]
        path, pos = replay_path(r.q_path, rows)
        out.append(
            RunRows(
                r.name,
                path,
                pos,
                np.array([r.points[j].tip_mm for j in chosen]),
                np.array([r.points[j].tension_N for j in chosen]),
            )
        )
    return out, spreads


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


def _identification(
    prob: ReplayProblem,
    nominal: RobotParams,
    fitted: RobotParams,
    sol: replay_fit.ReplayFit,
    fixed: list[NotIdentified],
    points: list[DwellPoint],
) -> Identification:
    warnings = [
        f"{e.name}: fitted value {e.value:.4g} is ON ITS BOUND ({e.parameter.lower:.4g} .. "
        f"{e.parameter.upper:.4g}): the data push it out of its admissible range"
        for e in sol.estimates
        if e.at_bound
    ]
    warnings += [
        f"{e.name}: 95 % interval reaches its bound and is reported clipped there "
        f"[{e.ci95[0]:.4g}, {e.ci95[1]:.4g}]: the log does not bound it on that side"
        for e in sol.estimates
        if e.ci_at_bound and not e.at_bound
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
