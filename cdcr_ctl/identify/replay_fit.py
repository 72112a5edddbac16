"""Output-error fit of keypoint and tip-only logs: the forward replay is the model.

A quasi-static keypoint log is an actuator path q(t) and, at each row, the tracked tip (and
maybe the load cells). The forward model (:func:`cdcr_ctl.model.cc_disk.forward.replay`: Qi et al.
2023 eq. 9-15 statics, eq. 16-24 disk friction with stick memory, eq. 33-37 cable compatibility)
turns the path into a tip and tensions per row, keeping the friction memory from row to row as
the rig does. For candidate parameters g (:func:`cdcr_ctl.identify.keypoints.candidates`) the
residuals are, per fitted row i,

    r_tip,i = (p_model,i(g) - p_measured,i) / sigma_tip          (3 per row, mm / mm)
    r_cell,i = (T_model,i(g) - T_measured,i) / sigma_cell        (one per finite load cell)

and the fit is min_g sum r^2 (``scipy.optimize.least_squares``, trust region, bounds). The
Jacobian of tip residuals comes from one replay that carries the solution's sensitivities
along the path (:mod:`cdcr_ctl.model.cc_disk.forward.sensitivity`: implicit differentiation of
every solve, the friction memory's sensitivity handed on from row to row), about twice the
cost of a plain replay for ten parameters; with load-cell residuals or a play parameter
(``backlash_mm``, which acts before the solve) it is forward differences, one replay per
parameter, run in parallel processes. Every replay starts at the run's start (straight,
pretensioned) and follows the same friction history as the rig did; no pose or tension is a
free unknown, so stick after a reversal, slack and sliding come out of the replay and never
from a rule applied to the rows.

Statistics: with J the weighted Jacobian at the solution (columns in the fit variables, ln of
positive parameters, rad for hole offsets) and chi2_red = sum r^2 / (m - n),
cov = s2 (J^T J)^-1 with s2 = max(1, chi2_red): when the residual exceeds the assumed noise
the intervals are widened by sqrt(chi2_red) (the report says so).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from cdcr_ctl.identify.fit_types import Estimate
from cdcr_ctl.identify.parameters import FitParameter, apply_values
from cdcr_ctl.model.cc_disk.effects import BacklashPlay, with_cable_play
from cdcr_ctl.model.cc_disk.forward import ForwardStepper, replay
from cdcr_ctl.model.cc_disk.forward.sensitivity import replay_sensitivity
from cdcr_ctl.model.cc_disk.friction_law import LawTransfer
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.params import Effects, Location, RobotParams

#: Step of the forward differences in the fit variables (ln value, or rad): small next to a
#: tolerance (25 %, 1 deg = 0.017 rad), large next to the forward solve's convergence.
DIFF_STEP = 1e-4
#: Step of the raw functions' differences of the sensitivity replay (fit variables): no
#: solve in between, so only rounding (~1e-15 relative) limits it from below.
SENS_STEP = 1e-6
#: CPU cost of a sensitivity replay per parameter, in plain replays of the same rows (measured
#: on the 1600-row hard world's chosen rows: 10 parameters 1.4-1.9 replays).
SENS_COST_PER_PARAM = 0.08
#: Trial evaluations per Jacobian of a trust-region fit (measured there: 17 for 6).
TRIALS_PER_JACOBIAN = 3.0
#: A fit stops when a step lowers the sum of squares by less than this many (s2-scaled)
#: variances: near the minimum a Gauss-Newton step's decrease is the squared distance to it
#: in standard deviations, so the fit ends within ~0.2 sigma of it (:func:`fit`).
STOP_DECREASE = 0.04
#: Evaluations a fit runs whatever its deadline (three trust-region steps and their checks).
MIN_EVALUATIONS = 4
#: Weighted residual (noise standard deviations) of a row the replay could not solve.
FAILED_ROW_RESIDUAL = 20.0


@dataclass(frozen=True)
class RunRows:
    """One run as the replay fit sees it: the actuator path (N, K) mm from the run's start to
    the last fitted row, the fitted rows' indices into it, their tips (n, 3) mm and load-cell
    tensions (n, K) N (NaN where none)."""

    name: str
    q_path: np.ndarray
    rows: np.ndarray
    tip_mm: np.ndarray
    tension_N: np.ndarray


@dataclass(frozen=True)
class ReplayProblem:
    """Weighted residuals of the fitted rows for parameter values (module docstring)."""

    base: RobotParams
    effects: Effects
    runs: tuple[RunRows, ...]
    locations: tuple[Location, ...]  # load-cell location per cable
    tip_noise_mm: float
    tension_noise_N: float
    #: the disk friction's law (``robot.friction_law``; None: the capstan law), see :func:`stepper`
    friction_law: FrictionLawShape | None = None

    def params_of(self, fps: Sequence[FitParameter], x: Sequence[float]) -> RobotParams:
        return apply_values(self.base, fps, [fp.from_var(v) for fp, v in zip(fps, x, strict=True)])

    def residuals_of(self, params: RobotParams) -> tuple[np.ndarray, np.ndarray, int]:
        """(weighted residuals, which are tip rows (bool), rows with no static solution)."""
        out: list[np.ndarray] = []
        is_tip: list[np.ndarray] = []
        failed = 0
        for r in self.runs:
            rep = replay(stepper(params, self.effects, self.friction_law), r.q_path)
            failed += len(rep.failed)
            d = (rep.tip_mm[r.rows] - r.tip_mm) / self.tip_noise_mm
            out.append(np.where(np.isfinite(d), d, FAILED_ROW_RESIDUAL).ravel())
            is_tip.append(np.ones(d.size, bool))
            cell = np.isfinite(r.tension_N)
            if cell.any():
                at_act = np.array([loc == "actuator" for loc in self.locations], bool)
                T = np.where(at_act, rep.tension_actuator_N[r.rows], rep.tension_base_N[r.rows])
                e = (T - r.tension_N) / self.tension_noise_N
                e = np.where(np.isfinite(e), e, FAILED_ROW_RESIDUAL)[cell]
                out.append(e)
                is_tip.append(np.zeros(e.size, bool))
        return np.concatenate(out), np.concatenate(is_tip), failed

    def analytic(self, fps: Sequence[FitParameter]) -> bool:
        """Whether the sensitivity replay gives the Jacobian (:func:`analytic_jacobian`)."""
        cells = any(np.isfinite(r.tension_N).any() for r in self.runs)
        return analytic_jacobian(self.base, fps, cells, self.friction_law)

    def is_tip(self) -> np.ndarray:
        """Which entries of the residual vector are tip residuals (the others: load cells)."""
        out: list[np.ndarray] = []
        for r in self.runs:
            out.append(np.ones(r.tip_mm.size, bool))
            out.append(np.zeros(int(np.isfinite(r.tension_N).sum()), bool))
        return np.concatenate(out)

    def residuals(self, fps: Sequence[FitParameter], x: Sequence[float]) -> np.ndarray:
        return self.residuals_of(self.params_of(fps, x))[0]


def analytic_jacobian(
    params: RobotParams,
    fps: Sequence[FitParameter],
    cells: bool,
    law: FrictionLawShape | None = None,
) -> bool:
    """Whether the Jacobian comes from the sensitivity replay (module docstring): no load-cell
    residuals (``cells``), no parameter of the actuator effects (play), elastic cables, and the
    capstan law (the sensitivity replay differentiates the capstan chain; another ``law`` is
    differentiated by forward differences of :func:`stepper`'s replays)."""
    return (
        not cells
        and (law is None or law.capstan)
        and not any(fp.kind == "backlash" for fp in fps)
        and all(math.isfinite(c.EA_N) for c in params.cables)
    )


def planned_replays(n_params: int, analytic: bool, n_jacobians: int) -> float:
    """Plain replays of its rows a fit of ``n_jacobians`` Jacobians costs: forward differences
    ``n_params`` + 1 replays per Jacobian (the trial point included); with sensitivities one
    replay carrying them (:data:`SENS_COST_PER_PARAM` of a replay per parameter on top) and
    :data:`TRIALS_PER_JACOBIAN` trial evaluations."""
    if not analytic:
        return float(n_jacobians * (n_params + 1))
    return n_jacobians * (1.0 + SENS_COST_PER_PARAM * n_params + TRIALS_PER_JACOBIAN)


def effects_of(params: RobotParams, effects: Effects) -> Effects:
    """``effects`` with the transmission play of ``params``' cables (``backlash_mm``) in place
    of any play built from the config's values, so a fitted play takes effect."""
    rest = tuple(e for e in effects.actuator if not isinstance(e, BacklashPlay))
    return with_cable_play(params, replace(effects, actuator=rest))


def stepper(
    params: RobotParams, effects: Effects, law: FrictionLawShape | None = None
) -> ForwardStepper:
    """The forward stepper of a replay: ``params`` with the play of their cables
    (:func:`effects_of`) and the disk friction's ``law`` (the config's ``robot.friction_law``;
    None or the capstan shape: Qi et al. 2023 eq. 16-24). Another law replaces the stepper's
    force-transfer chain by its :class:`~cdcr_ctl.model.cc_disk.friction_law.LawTransfer` at
    rest: a keypoint row is settled, the cables do not slide while it is logged (as the
    tension-log fit's dwells, :func:`cdcr_ctl.identify.problem.dwell_transfer`)."""
    st = ForwardStepper(params, effects_of(params, effects))
    if law is not None and not law.capstan:
        st.model.ft = LawTransfer(params, st.model.effects, law)
    return st


# --- the Jacobian, one replay per column, in worker processes ------------------------------


def _replay_with(args: tuple[ReplayProblem, RobotParams]) -> tuple[np.ndarray, float]:
    """Weighted residuals of one parameter set and the CPU time (s) its replay took."""
    c0 = time.process_time()
    res = args[0].residuals_of(args[1])[0]
    return res, time.process_time() - c0


def _sensitivity_task(args: tuple) -> tuple[np.ndarray, float]:
    """Jacobian (weighted tip residuals x parameters) by the sensitivity replay, and the CPU
    time (s) it took."""
    c0 = time.process_time()
    prob, params, variants, steps = args
    effects = effects_of(params, prob.effects)
    cols: list[np.ndarray] = []
    for r in prob.runs:
        _, dtip = replay_sensitivity(params, effects, variants, steps, r.q_path)
        cols.append(dtip[r.rows].reshape(-1, len(variants)) / prob.tip_noise_mm)
    return np.vstack(cols), time.process_time() - c0


class Evaluator:
    """Residuals and forward-difference Jacobians of a :class:`ReplayProblem`, the columns
    computed in ``jobs`` worker processes (1: in this process). Use as a context manager.

    ``cpu_s`` sums the CPU time of every replay it ran (in whichever process): a measure of
    the work done that does not grow with the machine's load, as a wall clock does."""

    def __init__(self, prob: ReplayProblem, jobs: int | None = None) -> None:
        self.prob = prob
        self.jobs = max(1, min(jobs or (os.cpu_count() or 1), 8))
        self.pool: Executor | None = None
        self.n_replays = 0
        self.cpu_s = 0.0

    def __enter__(self) -> Evaluator:
        if self.jobs > 1:
            self.pool = ProcessPoolExecutor(self.jobs)
        return self

    def set_problem(self, prob: ReplayProblem) -> None:
        """Evaluate ``prob`` from now on (sent to the workers with the next map)."""
        self.prob = prob

    def __exit__(self, *exc: object) -> None:
        if self.pool is not None:
            self.pool.shutdown()

    def map_params(self, plist: Sequence[RobotParams]) -> list[np.ndarray]:
        """Weighted residuals for each parameter set (in parallel)."""
        self.n_replays += len(plist)
        tasks = [(self.prob, p) for p in plist]
        if self.pool is None:
            outs = [_replay_with(t) for t in tasks]
        else:
            # the problem travels with every task (a few hundred kB against a replay of seconds)
            outs = list(self.pool.map(_replay_with, tasks))
        self.cpu_s += sum(c for _, c in outs)
        return [r for r, _ in outs]

    def jacobian(
        self,
        fps: Sequence[FitParameter],
        x: np.ndarray,
        f0: np.ndarray,
        hi: np.ndarray,
        analytic: bool | None = None,
    ) -> np.ndarray:
        """Jacobian of the weighted residuals at ``x``: the sensitivity replay when the
        residuals are tips only and no parameter acts before the solve (module docstring),
        else forward differences (backward at an upper bound); ``analytic`` False: forward
        differences in any case (None: as the problem allows)."""
        if self.prob.analytic(fps) if analytic is None else analytic and self.prob.analytic(fps):
            steps = np.where(x + SENS_STEP <= hi, SENS_STEP, -SENS_STEP)
            variants = []
            for j, h in enumerate(steps):
                xj = np.array(x, dtype=float)
                xj[j] += h
                variants.append(self.prob.params_of(fps, xj))
            task = (self.prob, self.prob.params_of(fps, x), variants, steps)
            self.n_replays += 1
            if self.pool is None:
                J, cpu = _sensitivity_task(task)
            else:
                J, cpu = self.pool.submit(_sensitivity_task, task).result()
            self.cpu_s += cpu
            return J
        steps = np.where(x + DIFF_STEP <= hi, DIFF_STEP, -DIFF_STEP)
        xs = []
        for j, h in enumerate(steps):
            xj = np.array(x, dtype=float)
            xj[j] += h
            xs.append(xj)
        cols = self.map_params([self.prob.params_of(fps, xj) for xj in xs])
        return np.column_stack([(c - f0) / h for c, h in zip(cols, steps, strict=True)])


@dataclass
class ReplayFit:
    """Result of :func:`fit`: values in natural units, estimates with 95 % intervals."""

    x: np.ndarray
    estimates: list[Estimate]
    chi2_reduced: float
    s2: float  # variance factor applied to the intervals (max(1, chi2_reduced))
    n_residuals: int
    res_before: np.ndarray
    res_after: np.ndarray
    is_tip: np.ndarray
    nfev: int
    message: str


class _OutOfTime(Exception):
    """Raised inside the least-squares loop when the fit's deadline has passed."""


def fit(
    ev: Evaluator,
    fps: Sequence[FitParameter],
    scales: Sequence[float],
    max_nfev: int,
    first: tuple[np.ndarray, np.ndarray] | None = None,
    deadline: float = math.inf,
    progress: Callable[[str], None] | None = None,
    cpu_budget_s: float = math.inf,
) -> ReplayFit:
    """Least squares over ``fps`` from their nominal values (module docstring); ``scales``
    their tolerances in the fit variables (``x_scale``); ``first``: (residuals, Jacobian) at
    the nominal values, already computed (the observability step), reused once.

    ``deadline`` (time.monotonic()): no new evaluation starts after it once
    :data:`MIN_EVALUATIONS` have run (a machine too slow for the budget still takes a few
    steps from the nominal values); the best point seen is kept and the intervals come from
    one more Jacobian there. ``cpu_budget_s``: the same limit on the CPU time of the fit's
    replays (:attr:`Evaluator.cpu_s`, counted from the call): the fit then takes the same
    steps on a loaded machine as on an idle one. ``progress``: called with a line
    after every evaluation. Intervals are computed in the fit variables and clipped to the
    parameter's bounds (:attr:`Estimate.ci_at_bound` says when: the log does not bound it)."""
    prob = ev.prob
    x0 = np.array([fp.to_var(fp.nominal) for fp in fps])
    lo = np.array([fp.var_bounds()[0] for fp in fps])
    hi = np.array([fp.var_bounds()[1] for fp in fps])
    # a nominal on its bound (a play of 0): start a tenth of its scale inside, where the
    # trust region's bound scaling does not freeze it
    x_nom = x0
    sc = np.asarray(scales, dtype=float)
    x0 = np.minimum(np.maximum(x0, lo + 0.1 * sc), hi - 0.1 * sc)
    cache: dict[bytes, np.ndarray] = {}
    jac0 = None
    if first is not None and np.array_equal(x0, x_nom):
        cache[x0.tobytes()] = first[0]
        jac0 = first[1]
    best: dict[str, object] = {"cost": math.inf, "x": x0, "f": None}
    t_start = time.monotonic()
    cpu_start = ev.cpu_s

    n_eval = [0]

    def spent() -> bool:
        over = time.monotonic() > deadline or ev.cpu_s - cpu_start > cpu_budget_s
        return n_eval[0] >= MIN_EVALUATIONS and over

    def fun(x: np.ndarray) -> np.ndarray:
        key = np.asarray(x, float).tobytes()
        if key not in cache:
            if spent():
                raise _OutOfTime
            n_eval[0] += 1
            cache.clear() if len(cache) > 8 else None
            cache[key] = ev.map_params([prob.params_of(fps, x)])[0]
        f = cache[key]
        c = float(f @ f)
        if c < best["cost"]:  # type: ignore[operator]
            best.update(cost=c, x=np.array(x, float), f=f)
        if progress is not None:
            progress(
                f"  fit: {ev.n_replays} replays, chi^2 sum {c:.4g} (best {best['cost']:.4g}), "
                f"{time.monotonic() - t_start:.0f} s, replays' CPU {ev.cpu_s - cpu_start:.0f} s"
            )
        return f

    def jac(x: np.ndarray) -> np.ndarray:
        if jac0 is not None and np.array_equal(x, x0):
            return jac0
        if spent():
            raise _OutOfTime
        return ev.jacobian(fps, np.asarray(x, float), fun(x), hi)

    if first is not None:
        r_before, is_tip = first[0], prob.is_tip()
    else:
        r_before, is_tip, _ = prob.residuals_of(prob.params_of(fps, x_nom))
    try:
        # dF < ftol F stops: F is s2 (m - n) at the minimum (s2 = max(1, chi2_red))
        ftol = max(1e-8, STOP_DECREASE / max(r_before.size - len(fps), 1))
        sol = least_squares(
            fun, x0, jac=jac, bounds=(lo, hi), x_scale=sc, max_nfev=max_nfev, ftol=ftol
        )
        x_best, f_best, J = sol.x, sol.fun, sol.jac
        nfev, message = int(sol.nfev), str(sol.message)
    except _OutOfTime:
        x_best = np.asarray(best["x"], float)
        f_best = best["f"] if best["f"] is not None else fun(x_best)
        J = ev.jacobian(fps, x_best, np.asarray(f_best), hi)
        nfev, message = len(cache), "stopped at the time budget (best point kept)"
    return _result(fps, x_best, np.asarray(f_best), J, lo, hi, r_before, is_tip, nfev, message)


def _result(fps, x, f, J, lo, hi, r_before, is_tip, nfev, message) -> ReplayFit:
    m, n = f.size, len(fps)
    chi2 = float(f @ f) / max(m - n, 1)
    s2 = max(1.0, chi2)
    cov = np.linalg.pinv(J.T @ J) * s2
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    est: list[Estimate] = []
    for fp, v, s, a, b in zip(fps, x, sd, lo, hi, strict=True):
        z = 1.959964 * s
        val = fp.from_var(v)
        std = val * s if fp.log else s
        at_bound = bool(min(v - a, b - v) < 1e-6)
        lo_v, hi_v = v - z, v + z
        clipped = not (a < lo_v and hi_v < b)
        ci = (fp.from_var(max(lo_v, a)), fp.from_var(min(hi_v, b)))
        est.append(Estimate(fp, val, std, ci, at_bound, ci_at_bound=clipped))
    return ReplayFit(x, est, chi2, s2, m, r_before, f, is_tip, nfev, message)


def rms_by_kind(res: np.ndarray, is_tip: np.ndarray, prob: ReplayProblem) -> dict[str, float]:
    """RMS in natural units: tip distance per row (mm) and load-cell error (N)."""
    out = {"tip": math.nan, "cell": math.nan}
    t = res[is_tip]
    if t.size:
        out["tip"] = float(np.sqrt(np.mean(np.sum(t.reshape(-1, 3) ** 2, axis=1)))) * (
            prob.tip_noise_mm
        )
    c = res[~is_tip]
    if c.size:
        out["cell"] = float(np.sqrt(np.mean(c**2))) * prob.tension_noise_N
    return out
