"""The model-discrepancy workflow: runs in, the missing effect and how much it explains out.

``analyse(run_dirs)``:

1. load and align every run (:mod:`~cdcr_ctl.discrepancy.alignment`): the controller's model,
   the input path, the measurements, noise levels;
2. simulate the baseline (the controller's model), estimate from its residual when each row's
   tracker sample was taken (:mod:`~cdcr_ctl.discrepancy.timing`; every later prediction is
   evaluated at those instants) and the tracker noise, and localise the disagreement
   (:mod:`~cdcr_ctl.discrepancy.localise`);
3. one forward simulation per parameter of every applicable candidate term
   (:data:`~cdcr_ctl.model.cc_disk.effects.CANDIDATES`), the linearised fits of every term and pair,
   blocked cross-validation, AIC/BIC and the significance rule
   (:mod:`~cdcr_ctl.discrepancy.selection`);
4. the nonlinear refit of the winner, the tracker's common delay re-estimated with the refitted
   model, residuals before and after, the tip gap shrink.

Simulations run in ``jobs`` worker processes when ``jobs > 1``; a progress bar (tqdm, on stderr)
counts them.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from cdcr_ctl.discrepancy.alignment import (
    MIN_TIP_SIGMA_MM,
    AlignedRun,
    align_run,
    residual_noise_sigma,
)
from cdcr_ctl.discrepancy.design import lag_split, suspect_lag
from cdcr_ctl.discrepancy.gap import frame_ids, gap_rms, rms, windowed_error, windowed_floor
from cdcr_ctl.discrepancy.localise import Table, localise
from cdcr_ctl.discrepancy.refine import choose_refinement, maybe_pair
from cdcr_ctl.discrepancy.selection import (
    Design,
    Refit,
    Selection,
    active_terms,
    apply_all,
    compare,
    entry_vector,
    far_wanted,
    predicted_vector,
    refinements,
    refit,
    split_refinements,
)
from cdcr_ctl.discrepancy.simulate import Prediction, model_part, simulate_model, with_tip_map
from cdcr_ctl.discrepancy.timing import delay_bound_s, estimate_timing
from cdcr_ctl.errors import RigError
from cdcr_ctl.model.cc_disk.effects import CANDIDATES, EffectTerm, ModelSpec


@dataclass
class RunOutcome:
    """Per run: tip RMS gap (mm) and tension RMS gap (N) before and after the refit, and the
    tracker noise floor of the tip RMS (sqrt(3) sigma_tip, mm): the part no model can remove.
    ``tip_gap_*_mm``: the same with the error averaged over :data:`~.gap.GAP_WINDOW_S` (the
    model's systematic error; the floor is the averaged noise's, :mod:`~.gap`).
    ``lag_s``: the tracker's mean delay behind the rows (the run's timing model); ``lag_suspect``:
    why that delay is not trusted (empty when the log's timing supports it)."""

    name: str
    tip_noise_floor_mm: float
    tip_rms_before_mm: float
    tip_rms_after_mm: float
    tension_rms_before_N: float
    tension_rms_after_N: float
    lag_s: float
    tables: list[Table]
    lag_suspect: str
    t_s: np.ndarray
    tip_err_before_mm: np.ndarray
    tip_err_after_mm: np.ndarray
    tip_gap_before_mm: float = math.nan
    tip_gap_after_mm: float = math.nan
    tip_gap_floor_mm: float = math.nan


@dataclass
class DiscrepancyResult:
    """Everything the report shows."""

    runs: list[AlignedRun]
    terms: list[EffectTerm]
    design: Design
    selection: Selection
    refit: Refit | None
    outcomes: list[RunOutcome]
    notes: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    simulations: int = 0

    @property
    def named(self) -> str | None:
        """Name of the effect (or ``a + b``) found missing, None when none is named."""
        return self.selection.chosen.name if self.selection.chosen is not None else None

    @property
    def tip_rms_before_mm(self) -> float:
        return _pooled([o.tip_rms_before_mm for o in self.outcomes], self.outcomes)

    @property
    def tip_rms_after_mm(self) -> float:
        return _pooled([o.tip_rms_after_mm for o in self.outcomes], self.outcomes)

    @property
    def tip_noise_floor_mm(self) -> float:
        return _pooled([o.tip_noise_floor_mm for o in self.outcomes], self.outcomes)

    @property
    def gap_shrink(self) -> float:
        """1 - RMS after / RMS before of the measured tip gap (0 when nothing was refitted)."""
        b = self.tip_rms_before_mm
        return 1.0 - self.tip_rms_after_mm / b if b > 0 else 0.0

    @property
    def tip_gap_mm(self) -> tuple[float, float, float]:
        """The tip gap with the error averaged over :data:`~.gap.GAP_WINDOW_S`, before and after,
        and its noise floor (mm, pooled over the runs)."""
        o = self.outcomes
        return (
            _pooled([x.tip_gap_before_mm for x in o], o),
            _pooled([x.tip_gap_after_mm for x in o], o),
            _pooled([x.tip_gap_floor_mm for x in o], o),
        )

    @property
    def tip_gap_shrink(self) -> float:
        """1 - after / before of :attr:`tip_gap_mm` (0 when nothing was refitted)."""
        b, a, _ = self.tip_gap_mm
        return 1.0 - a / b if b > 0 else 0.0

    @property
    def systematic_gap_mm(self) -> tuple[float, float]:
        """Tip gap beyond the tracker noise, before and after: sqrt(RMS^2 - floor^2) (mm)."""
        f2 = self.tip_noise_floor_mm**2
        return (
            math.sqrt(max(self.tip_rms_before_mm**2 - f2, 0.0)),
            math.sqrt(max(self.tip_rms_after_mm**2 - f2, 0.0)),
        )

    @property
    def systematic_gap_shrink(self) -> float:
        """1 - systematic gap after / before (the share of the model error removed)."""
        b, a = self.systematic_gap_mm
        return 1.0 - a / b if b > 0 else 0.0


def _pooled(values: list[float], outcomes: list[RunOutcome]) -> float:
    n = [np.isfinite(o.tip_err_before_mm).sum() for o in outcomes]
    v = np.asarray(values)
    ok = np.isfinite(v)
    if not ok.any():
        return float("nan")
    w = np.asarray(n, dtype=float)[ok]
    return float(np.sqrt(np.sum(w * v[ok] ** 2) / max(w.sum(), 1)))


def _sim_job(args: tuple[ModelSpec, AlignedRun]) -> Prediction:
    spec, run = args
    return simulate_model(spec, run)


class _Simulator:
    """Runs forward simulations (here or in worker processes), caches them by the model part of
    the spec (a changed tip map needs no new simulation), counts them for the progress bar."""

    def __init__(self, runs: Sequence[AlignedRun], jobs: int, bar) -> None:
        self.runs = runs
        self.jobs = jobs
        self.bar = bar
        self.count = 0
        self.cache: dict[tuple[str, int], Prediction] = {}
        self.pool = ProcessPoolExecutor(jobs) if jobs > 1 else None

    @staticmethod
    def key(spec: ModelSpec, ri: int) -> tuple[str, int]:
        return repr(model_part(spec)), ri

    def __call__(self, spec: ModelSpec, ri: int) -> Prediction:
        """What ``spec`` predicts for run ``ri`` as the tracker reports it (timing, tip map)."""
        return with_tip_map(spec, self.timed(self.raw(spec, ri), ri))

    def raw(self, spec: ModelSpec, ri: int) -> Prediction:
        """The model part's prediction at the row times (no tracker timing, no tip map)."""
        m = model_part(spec)
        if m.coupling_gain is not None:  # a blend of the two cached switch positions
            lam = m.coupling_gain
            a = self.raw(replace(m, coupling_gain=0.0), ri)
            b = self.raw(replace(m, coupling_gain=1.0), ri)
            return Prediction(
                (1 - lam) * a.tip_mm + lam * b.tip_mm,
                (1 - lam) * a.tension_N + lam * b.tension_N,
                (1 - lam) * a.psi + lam * b.psi,
                a.failures + b.failures,
            )
        k = self.key(spec, ri)
        if k not in self.cache:
            self.cache[k] = simulate_model(spec, self.runs[ri])
            self._tick()
        return self.cache[k]

    def timed(self, pred: Prediction, ri: int) -> Prediction:
        """``pred`` with its tip, tip velocity and acceleration at the instants the tracker
        samples were taken."""
        run = self.runs[ri]
        v = np.gradient(pred.tip_mm, run.t_s, axis=0)
        a = np.gradient(v, run.t_s, axis=0)
        return replace(
            pred,
            tip_mm=run.timing.apply(pred.tip_mm),
            tip_velocity_mm_s=run.timing.apply(v),
            tip_accel_mm_s2=run.timing.apply(a),
        )

    def many(self, items: list[tuple[ModelSpec, int]]) -> list[Prediction]:
        todo = {}
        for s, i in items:
            k = self.key(s, i)
            if k not in self.cache and k not in todo:
                todo[k] = (s, i)
        if self.pool is None or len(todo) < 2:
            for s, i in todo.values():
                self(s, i)
        else:
            futs = {k: self.pool.submit(_sim_job, (s, self.runs[i])) for k, (s, i) in todo.items()}
            for k, f in futs.items():
                self.cache[k] = f.result()
                self._tick()
        return [self(s, i) for s, i in items]

    def _tick(self) -> None:
        self.count += 1
        if self.bar is not None:
            self.bar.update(1)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()


def analyse(
    run_dirs: Sequence[str | Path],
    rig_config: str | Path | None = None,
    candidates: Sequence[EffectTerm] = CANDIDATES,
    model_effects: dict[str, bool] | None = None,
    folds: int = 5,
    pairs: bool = True,
    max_points: int = 700,
    jobs: int = 2,
    progress: bool = True,
    refit_evals: int = 8,
) -> DiscrepancyResult:
    """Run the workflow on ``run_dirs`` (see module doc). Raises :class:`RigError` for runs of
    different rigs or runs that cannot be analysed."""
    t0 = time.monotonic()
    runs = [align_run(d, rig_config, model_effects, max_points=max_points) for d in run_dirs]
    if not runs:
        raise RigError("no runs given")
    K = {r.n_cables for r in runs}
    S = {r.spec.params.n_segments for r in runs}
    if len(K) > 1 or len(S) > 1:
        raise RigError("the runs are of different rigs (segment/cable counts differ)")
    terms, notes = active_terms(runs, candidates)
    n_cols = sum(len(t.parameters(runs[0].spec)) for t in terms if t.kind != "measurement")
    total = len(runs) * (1 + n_cols + refit_evals)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc="discrepancy", unit="sim", leave=False)
    sim = _Simulator(runs, jobs, bar)
    try:
        raw = sim.many([(r.spec, i) for i, r in enumerate(runs)])  # no timing estimated yet
        for r, b in zip(runs, raw, strict=True):
            _estimate_timing(r, b)
        baselines = sim.many([(r.spec, i) for i, r in enumerate(runs)])
        first, later = split_refinements(terms)
        design, selection = compare(runs, first, baselines, folds, pairs, sim)
        extra = refinements(later, selection)
        far = far_wanted(first, selection)
        lead = (selection.pair or selection.best).name
        if extra or far:  # a refinement of the leading effect, far starts: compared again
            design, selection = compare(runs, [*first, *extra], baselines, folds, pairs, sim, far)
        if extra:
            notes.append(
                f"refined {', '.join(t.refines for t in extra)}: compared again with"
                f" {', '.join(t.name for t in extra)}"
            )
        if far:
            notes.append(
                f"{lead} led: compared again with the far start points (quarter and"
                " half turns of the mount)"
            )
        rf = None
        if selection.chosen is not None:
            rf = refit(design, runs, selection.chosen, sim, max_nfev=refit_evals)
            rf = choose_refinement(design, runs, selection, rf, sim, refit_evals)
            rf = maybe_pair(design, runs, selection, rf, sim, refit_evals)
        baselines, nuis_before = _final_timing(design, runs, rf, sim)
        outcomes = _outcomes(runs, baselines, design, rf, nuis_before)
    finally:
        sim.close()
        if bar is not None:
            bar.close()
    for r in runs:
        notes += [f"{r.name}: {n}" for n in r.notes]
    fails = sum(b.failures for b in baselines)
    if fails:
        notes.append(f"{fails} baseline steps the model could not solve (last solution kept)")
    return DiscrepancyResult(
        runs=runs,
        terms=terms,
        design=design,
        selection=selection,
        refit=rf,
        outcomes=outcomes,
        notes=notes,
        elapsed_s=time.monotonic() - t0,
        simulations=sim.count,
    )


def _estimate_timing(run: AlignedRun, base: Prediction) -> None:
    """The tracker timing and tip noise of ``run`` from the baseline's residual (in place)."""
    if not np.isfinite(run.tip_mm).any():
        return
    run.timing = estimate_timing(run.t_s, run.cycle, run.tip_mm, base.tip_mm)
    sigma = residual_noise_sigma(run.tip_mm, run.timing.apply(base.tip_mm), MIN_TIP_SIGMA_MM)
    run.notes.append(run.timing.note)
    run.notes.append(
        f"tip noise sigma {sigma:.4f} mm from the timed residual (from the samples alone:"
        f" {run.sigma_tip_mm:.4f} mm, which includes the sampling jitter of the moving tip)"
    )
    run.sigma_tip_mm = sigma


def _final_timing(
    d: Design, runs: Sequence[AlignedRun], rf: Refit | None, sim: _Simulator
) -> tuple[list[Prediction], list[np.ndarray]]:
    """Fix each run's common tracker delay with the best model (the refit, or the controller's
    model when nothing was refitted), then predict both models with that one timing and fit
    their nuisance other than the lag (the load-cell offsets; in place for ``rf``). Returns the
    baselines and their nuisance per run."""
    nb_all, base_all, preds = [], [], []
    nuis_after = np.array(rf.nuisance, dtype=float) if rf is not None else None
    for ri, run in enumerate(runs):
        best = _refit_spec(rf, run) if rf is not None else run.spec
        if np.isfinite(run.tip_mm).any():
            start = _lag_of(d, run, nuis_after if rf is not None else _nuisance_fit(ri, d, d.r0))
            start += float(np.mean(run.timing.row_delay_s))
            model_tip = best.tip_map(sim.raw(best, ri).tip_mm)  # untimed, in the tracker's view
            bound = delay_bound_s(run.t_s, run.tip_mm)
            split = lag_split(run, model_tip, sim.raw(best, ri).psi)
            run.timing = run.timing.with_common_delay(run.tip_mm, model_tip, start, bound)
            run.notes.append(run.timing.note)
            why = suspect_lag(float(np.mean(run.timing.row_delay_s)), split)
            if why and not run.timing.suspect:
                run.timing = replace(run.timing, suspect=why)
        base = sim(run.spec, ri)
        base_all.append(base)
        nb_all.append(_without_lag(d, run, _nuisance_fit(ri, d, _run_residual(d, run, ri, base))))
        if rf is not None:
            pr = sim(best, ri)
            preds.append(pr)
            na = _without_lag(d, run, _nuisance_fit(ri, d, _run_residual(d, run, ri, pr)))
            cols = np.any(d.Nu[d.run == ri] != 0, axis=0)
            nuis_after[cols] = na[cols]
    if rf is not None:
        rf.predictions = preds
        rf.nuisance = nuis_after
    return base_all, nb_all


def _without_lag(d: Design, run: AlignedRun, nuis: np.ndarray) -> np.ndarray:
    """``nuis`` with the run's linear tracker-lag correction set to 0: once the timing is fixed
    by the best model, both models are compared at the same sampling instants (a model's error
    along the path must not pass for tracker delay)."""
    out = np.array(nuis, dtype=float)
    for i, n in enumerate(d.nu_names):
        if n.startswith(f"{run.name}: tracker lag"):
            out[i] = 0.0
    return out


def _lag_of(d: Design, run: AlignedRun, nuis: np.ndarray) -> float:
    """The fitted linear tracker-lag nuisance of ``run`` (s), 0 if it has none."""
    names = [i for i, n in enumerate(d.nu_names) if n == f"{run.name}: tracker lag (s)"]
    return float(nuis[names[0]]) if names else 0.0


def _run_residual(d: Design, run: AlignedRun, ri: int, pred: Prediction) -> np.ndarray:
    """Normalised residual of ``pred`` on the design's entries of run ``ri`` (0 elsewhere)."""
    m = d.run == ri
    r = np.zeros(len(d.r0))
    r[m] = _measured_vector(run, d.row[m], d.chan[m]) - predicted_vector(
        run, pred, d.row[m], d.chan[m]
    )
    return r


def _refit_spec(rf: Refit, run: AlignedRun) -> ModelSpec:
    return apply_all(rf.terms, run.spec, rf.values)


def _measured_vector(run: AlignedRun, rows: np.ndarray, chans: np.ndarray) -> np.ndarray:
    return entry_vector(run, run.tip_mm, run.tension_N, rows, chans)


def _nuisance_fit(run_i: int, d: Design, resid_entries: np.ndarray) -> np.ndarray:
    m = d.run == run_i
    Nu = d.Nu[m]
    keep = np.any(Nu != 0, axis=0)
    p = np.zeros(d.Nu.shape[1])
    if keep.any():
        p[keep] = np.linalg.lstsq(Nu[:, keep], resid_entries[m], rcond=None)[0]
    return p


def _corrected_tip_error(
    run: AlignedRun, pred: Prediction, d: Design, ri: int, nuis: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """Tip error (N, 3) mm and tension residual (N, K) N after removing the nuisance fitted to
    them (the load-cell offsets; the tracker lag is already in the run's timing, its linear
    nuisance is zero here: :func:`_final_timing`)."""
    m = d.run == ri
    rows, chans = d.row[m], d.chan[m]
    corr = d.Nu[m] @ nuis
    tip_e = run.tip_mm - pred.tip_mm
    tip_c = tip_e.copy()
    t_m = chans < 3
    tip_c[rows[t_m], chans[t_m]] -= corr[t_m] * run.sigma_tip_mm
    Te = None
    if run.tension_N is not None:
        Te = run.tension_N - pred.tension_N
        Te[rows[~t_m], chans[~t_m] - 3] -= corr[~t_m] * run.sigma_tension_N
    return tip_c, Te


def _outcomes(
    runs: Sequence[AlignedRun],
    baselines: Sequence[Prediction],
    d: Design,
    rf: Refit | None,
    nuis_before: Sequence[np.ndarray],
) -> list[RunOutcome]:
    out = []
    for ri, (run, base) in enumerate(zip(runs, baselines, strict=True)):
        nb = nuis_before[ri]
        eb, Tb = _corrected_tip_error(run, base, d, ri, nb)
        if rf is not None:
            after = rf.predictions[ri]
            ea, Ta = _corrected_tip_error(run, after, d, ri, rf.nuisance)
        else:
            after, ea, Ta = base, eb, Tb
        tables = localise(run, base)
        frames = frame_ids(run.tip_mm)
        wb, factor = windowed_error(run.t_s, eb, frames)
        wa = windowed_error(run.t_s, ea, frames)[0] if rf is not None else wb
        eb, ea = np.linalg.norm(eb, axis=1), np.linalg.norm(ea, axis=1)

        out.append(
            RunOutcome(
                name=run.name,
                tip_noise_floor_mm=math.sqrt(3.0) * run.sigma_tip_mm,
                tip_rms_before_mm=rms(eb),
                tip_rms_after_mm=rms(ea),
                tension_rms_before_N=rms(Tb),
                tension_rms_after_N=rms(Ta),
                lag_s=float(np.mean(run.timing.row_delay_s)),
                tables=tables,
                lag_suspect=run.timing.suspect,
                t_s=run.t_s,
                tip_err_before_mm=eb,
                tip_err_after_mm=ea,
                tip_gap_before_mm=gap_rms(wb),
                tip_gap_after_mm=gap_rms(wa),
                tip_gap_floor_mm=windowed_floor(run.sigma_tip_mm, factor),
            )
        )
    return out
