"""``discrepancy`` on quasi-static keypoint logs (rows ~0.5 s apart, no commanded pose).

The loop-log path (:mod:`.workflow`) finds motion phases and reversals from the commanded pose
and fits the tracker's lag from the tip's motion between 1-10 ms rows. A keypoint log has
neither: every row is settled, so

* reversals come from the *actuator path*: a cable reverses where the sign of its measured
  displacement step changes (steps smaller than
  :data:`~cdcr_ctl.identify.logkind.KEYPOINT_DIRECTION_EPS_MM` decide nothing);
* no lag is fitted: a settled keypoint carries no timing information (a tracker lag shifts
  nothing when the tip does not move), so the report says "not fitted" instead of a number;
* the effects searched are those real multi-segment robots show
  (:mod:`.keypoint_effects`: curvature not constant along a segment, tendon routing offsets,
  hysteresis per segment, base/registration error, gravity sag of the whole arm), each fitted
  alone on top of the config's forward replay from the rows before the hold-out cut (the
  replayed candidates from rows chosen to span the log, :mod:`cdcr_ctl.identify.rowselect`)
  and scored on the held-out end of the run (the last 30 % by time). The best one is *named*
  when it shrinks the held-out tip RMSE by at least ``NAME_SHRINK`` and predicts the held-out
  rows better than the runner-up beyond their noise: the paired drop of the squared tip error
  runner-up -> best, averaged in blocks of 10 consecutive rows, exceeds ``TIE_SE`` standard
  errors (:func:`cdcr_ctl.identify.keypoint_gate.heldout_gain`, the test of ``identify``'s
  gate). A tie is fitted jointly (:func:`nested_test`); a tie of ``registration`` with a
  replayed candidate that the joint fit leaves open is decided by whether the registration is
  one rigid frame across the poses (:func:`registration_test`, :mod:`.keypoint_rigid`).
  Otherwise both are reported and none is named.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cdcr_ctl.config.build_model import build_model, friction_law
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.discrepancy.keypoint_effects import (
    EFFECTS,
    EffectFit,
    kinematic_fits,
    problem_of,
    registered_on,
    replay_fit_effect,
)
from cdcr_ctl.discrepancy.keypoint_rigid import frame_rigidity
from cdcr_ctl.errors import RigError
from cdcr_ctl.identify import replay_fit
from cdcr_ctl.identify.keypoint_gate import heldout_gain
from cdcr_ctl.identify.keypoints import HOLDOUT_FRACTION, _choose_rows, _load, _noise
from cdcr_ctl.identify.logkind import KEYPOINT_DIRECTION_EPS_MM, detect_kind, split_by_time
from cdcr_ctl.identify.replay_fit import Evaluator
from cdcr_ctl.identify.rowselect import rows_for_budget
from cdcr_ctl.model.cc_disk.forward import replay
from cdcr_ctl.runlog.reader import load_run


def is_keypoint_log(run_dir: str | Path) -> bool:
    """Whether the run is a keypoint log (:func:`cdcr_ctl.identify.logkind.detect_kind`); a
    run the detection cannot classify (no tip, no actuator columns) is left to the loop path."""
    try:
        return detect_kind(load_run(run_dir))[0] == "keypoint"
    except RigError:
        return False


def reversals_from_path(q_mm: np.ndarray, eps_mm: float = KEYPOINT_DIRECTION_EPS_MM) -> np.ndarray:
    """Reversals per cable of an actuator path (N, K) mm: sign changes of the steps that move
    more than ``eps_mm`` (a smaller step keeps the last direction)."""
    dq = np.diff(np.asarray(q_mm, dtype=float), axis=0)
    out = np.zeros(dq.shape[1], dtype=int)
    for k in range(dq.shape[1]):
        d = dq[:, k]
        sgn = np.sign(d[np.isfinite(d) & (np.abs(d) > eps_mm)])
        out[k] = int(np.count_nonzero(np.diff(sgn) != 0)) if sgn.size > 1 else 0
    return out


#: Held-out shrink from which the best candidate is named (and beyond its noise).
NAME_SHRINK = 0.25
#: Standard errors by which the best candidate's held-out squared error must undercut the
#: runner-up's to be named (else a tie: nothing is named).
TIE_SE = 2.0
#: Budget of each replay-fitted candidate: CPU seconds of its replays (the same fit on a
#: loaded machine as on an idle one).
EFFECT_BUDGET_S = 20.0
#: What the report recommends when gravity sag ties with another candidate.
GRAVITY_HINT = (
    "to tell a sag apart, log bends towards and away from gravity up to ~1.3 rad per segment "
    "(the weight's lever arm changes with the pose; a registration or routing error does not "
    "change that way) over more rows, or add a known mass at the tip"
)
#: Replays of its rows a candidate's fit is planned for (rows per candidate from the budget).
EFFECT_REPLAYS = 30


@dataclass
class KeypointDiscrepancy:
    """Outcome of :func:`analyse_keypoints`."""

    verdict: str
    reversals: dict[str, list[int]]
    row_spacing_s: dict[str, float]
    fits: list[EffectFit]
    rmse_config: float
    n_fit: int
    n_candidates: int
    n_held: int
    elapsed_s: float
    effect: EffectFit | None = None
    spreads: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        out = [self.verdict]
        for name, rv in self.reversals.items():
            out.append(
                f"{name}: keypoint log, rows {self.row_spacing_s[name]:.3g} s apart; reversals "
                f"per cable from the actuator path: {rv} (total {sum(rv)})"
            )
        out.append("tracker lag: not fitted (settled keypoints carry no timing)")
        out.append(
            f"rows: {self.n_candidates} before the hold-out cut, {self.n_fit} of them fitted by "
            f"the replay candidates (chosen to span the log), {self.n_held} held out"
        )
        out += [f"  {s}" for s in self.spreads]
        out.append(f"config: held-out tip RMSE {self.rmse_config:.4g} mm")
        out.append("candidate effects, each fitted alone (held-out tip RMSE, shrink):")
        for f in sorted(self.fits, key=lambda f: f.rmse_heldout):
            vals = ", ".join(f"{n} {v:.4g}" for n, v in zip(f.names, f.values, strict=True))
            out.append(
                f"  {f.name:<12} {f.rmse_heldout:8.4g} mm  {100 * f.shrink:+6.1f} %  "
                f"({f.title}; {vals}; {f.seconds:.1f} s)"
            )
        out += [f"warning: {w}" for w in self.warnings]
        out.append(f"elapsed {self.elapsed_s:.1f} s")
        return out

    def as_dict(self) -> dict:
        e = self.effect
        return {
            "verdict": self.verdict,
            "effect": None
            if e is None
            else {
                "name": e.name,
                "title": e.title,
                "parameters": dict(zip(e.names, e.values, strict=True)),
            },
            "reversals": self.reversals,
            "tracker_lag_s": None,
            "heldout_tip_rmse_config_mm": self.rmse_config,
            "candidates": [
                {
                    "name": f.name,
                    "title": f.title,
                    "parameters": dict(zip(f.names, f.values, strict=True)),
                    "heldout_tip_rmse_mm": f.rmse_heldout,
                    "shrink_percent": 100 * f.shrink,
                    "seconds": f.seconds,
                }
                for f in self.fits
            ],
            "rows": {"fitted": self.n_fit, "before_cut": self.n_candidates, "held": self.n_held},
            "warnings": self.warnings,
            "elapsed_s": self.elapsed_s,
        }


def analyse_keypoints(
    cfg: RigConfig,
    run_dirs: Sequence[str | Path],
    max_points: int | None = None,
    effects: Sequence[str] = EFFECTS,
    jobs: int | None = None,
    progress: Callable[[str], None] | None = None,
    model_switches: dict[str, bool] | None = None,
    holdout: float = HOLDOUT_FRACTION,
) -> KeypointDiscrepancy:
    """Reversals, no lag, and the candidate effects of keypoint logs (module docstring)."""
    t0 = time.monotonic()
    say = progress or (lambda _l: None)
    model = build_model(cfg)
    params, eff, law = model.params, model.effects, friction_law(cfg.robot)
    if model_switches:
        eff = dataclasses.replace(eff, **model_switches)
    reversals: dict[str, list[int]] = {}
    spacing: dict[str, float] = {}
    for rd in run_dirs:
        run = load_run(rd)
        q = run.q_act() if run.has("q_act") else run.q_cmd()
        reversals[run.run_dir.name] = reversals_from_path(q).tolist()
        spacing[run.run_dir.name] = float(np.median(np.diff(run.t_s))) if len(run) > 1 else math.nan
    runs, _, warnings = _load(run_dirs, "keypoint", params.n_segments)
    points = [p for r in runs for p in r.points]
    fit_pts, held_pts = split_by_time(points, holdout)
    fit_keys = {(p.run, p.index) for p in fit_pts}
    held_keys = {(p.run, p.index) for p in held_pts}
    # the config's replay of every row: baseline, poses for the kinematic candidates
    full, xs, tm, tips, fmask, hmask = [], [], [], [], [], []
    c_rep = time.process_time()
    for r in runs:
        rep = replay(replay_fit.stepper(params, eff, law), r.q_path)
        rows = np.asarray(r.rows, dtype=int)
        tip = np.array([p.tip_mm for p in r.points])
        xs.append(rep.x[rows])
        tm.append(rep.tip_mm[rows])
        tips.append(tip)
        fmask.append(np.array([(p.run, p.index) in fit_keys for p in r.points]))
        hmask.append(np.array([(p.run, p.index) in held_keys for p in r.points]))
        tip_full = np.full((len(r.q_path), 3), np.nan)
        tip_full[rows] = tip
        held_full = np.zeros(len(r.q_path), bool)
        held_full[rows[hmask[-1]]] = True
        full.append((r.q_path, tip_full, held_full))
    n_rows_all = sum(len(r.q_path) for r in runs)
    s_row = (time.process_time() - c_rep) / max(n_rows_all, 1)
    X, TM, TIP = np.vstack(xs), np.vstack(tm), np.vstack(tips)
    F, H = np.concatenate(fmask), np.concatenate(hmask)
    base = _rmse_rows(TM[H] - TIP[H])
    say(
        f"config replay: {n_rows_all} rows, {s_row * 1e3:.2g} ms CPU per row; held-out RMSE "
        f"{base:.4g} mm"
    )
    fits: list[EffectFit] = []
    kin = [e for e in effects if e in ("curvature", "registration")]
    if kin:
        fits += [
            f for f in kinematic_fits(X, TM, TIP, F, H, params.lengths_mm, base) if f.name in kin
        ]
    rep_effects = [e for e in effects if e not in ("curvature", "registration")]
    with contextlib.ExitStack() as stack:
        ev: Evaluator | None = None
        n_cand = int(F.sum())
        n_fit = 0
        spreads: list[str] = []
        if rep_effects:
            nj = max(1, min(jobs or (os.cpu_count() or 1), 8))
            n_want = max_points or rows_for_budget(EFFECT_BUDGET_S, s_row, EFFECT_REPLAYS)
            rr, sp = _choose_rows(runs, fit_keys, n_want, n_cand)
            spreads = [ln.strip() for s_ in sp for ln in s_.lines()[1:]]
            n_fit = sum(len(r.rows) for r in rr)
            noise = max(_noise(runs)[0], 0.01)
            ev = stack.enter_context(Evaluator(problem_of(params, eff, rr, noise, law), nj))
            for name in rep_effects:
                say(f"candidate {name}: fitting {n_fit} rows")
                cpu = math.inf if max_points else EFFECT_BUDGET_S
                fits.append(replay_fit_effect(ev, params, eff, name, full, cpu, base, say))
        ranked = sorted(fits, key=lambda f: f.rmse_heldout)
        best = ranked[0] if ranked else None
        named = best if best is not None and best.shrink >= NAME_SHRINK else None
        tie = None
        nested: list[str] = []
        if named is not None and len(ranked) > 1:
            gain, se = _paired_gain(ranked[1], best)
            if not gain > TIE_SE * se:
                tie = ranked[1]
                joint = None
                if ev is not None:
                    cpu = math.inf if max_points else EFFECT_BUDGET_S
                    joint = _joint_fit(ev, params, eff, best, tie, full, cpu, base, say)
                if joint is not None:
                    fits.append(joint)
                    winner, nested = nested_test(best, tie, joint)
                    if winner is not None:
                        named, best, tie = winner, winner, None
                if tie is not None and ev is not None and "registration" in (best.name, tie.name):
                    rows = [np.asarray(r.rows, dtype=int) for r in runs]
                    winner, lines = registration_test(
                        ranked, best, tie, joint, (TM, TIP, F, H), rows, noise
                    )
                    nested += lines
                    if winner is not None:
                        named, best, tie = winner, winner, None
    if named is not None and tie is not None:
        verdict = (
            f"TWO EFFECTS EXPLAIN IT ALIKE, NONE NAMED: {best.title} ({best.name}, "
            f"{100 * best.shrink:.1f} % shrink) and {tie.title} ({tie.name}, "
            f"{100 * tie.shrink:.1f} %): the held-out squared tip error differs by "
            f"{gain:.3g} mm^2, less than {TIE_SE:g} standard errors ({se:.2g} mm^2); a log "
            "that tells them apart is needed"
        )
        if nested:
            verdict += "; fitted together: " + "; ".join(nested)
        if "gravity" in (best.name, tie.name):
            verdict += f"; {GRAVITY_HINT}"
        named = None
    elif named is not None:
        vals = ", ".join(f"{n} {v:.4g}" for n, v in zip(named.names, named.values, strict=True))
        verdict = (
            f"EFFECT: {named.title} ({named.name}): {vals}; held-out tip RMSE "
            f"{base:.4g} -> {named.rmse_heldout:.4g} mm ({100 * named.shrink:.1f} % shrink)"
        )
        if nested:
            verdict += "; alone it tied with the runner-up, fitted together: " + "; ".join(nested)
    elif best is not None:
        verdict = (
            f"NO EFFECT NAMED: the best candidate, {best.title} ({best.name}), shrinks the "
            f"held-out tip RMSE by {100 * best.shrink:.1f} % ({base:.4g} -> "
            f"{best.rmse_heldout:.4g} mm), less than {100 * NAME_SHRINK:.0f} %"
        )
    else:
        verdict = "NO EFFECT NAMED: no candidate searched"
    return KeypointDiscrepancy(
        verdict,
        reversals,
        spacing,
        fits,
        base,
        n_fit,
        n_cand,
        len(held_pts),
        time.monotonic() - t0,
        named,
        spreads,
        warnings,
    )


def _joint_fit(
    ev: Evaluator,
    params,
    eff,
    a: EffectFit,
    b: EffectFit,
    full,
    cpu: float,
    base: float,
    say: Callable[[str], None],
) -> EffectFit | None:
    """Candidates ``a`` and ``b`` fitted together: both replayed ones through the replay, a
    replayed one with ``registration`` on top of its replay; None for ``curvature`` (its
    profile is applied to the config's poses only)."""
    names = {a.name, b.name}
    if "curvature" in names or names == {"registration"}:
        return None
    if "registration" in names:
        other = a if b.name == "registration" else b
        return registered_on(other, full, base)
    say(f"candidates {a.name} and {b.name} tie: fitting them together")
    return replay_fit_effect(ev, params, eff, f"{a.name}+{b.name}", full, cpu, base, say)


def registration_test(
    ranked: Sequence[EffectFit],
    a: EffectFit,
    b: EffectFit,
    joint: EffectFit | None,
    rows_data: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    rows: Sequence[np.ndarray],
    noise_mm: float,
) -> tuple[EffectFit | None, list[str]]:
    """A tie of ``registration`` with a replayed candidate X that the joint fit did not
    separate: whether registration is one rigid frame (:mod:`.keypoint_rigid`, the rows split
    by how far X's fit moves the tip from the config's). ``rows_data``: (config's tips, logged
    tips, fitted-row mask, held-out mask) at every point row; ``rows``: each run's point rows
    in its path. When registration alone is not one frame, it cannot be the effect and X is
    named, if X shrinks the held-out RMSE by ``NAME_SHRINK`` and beats the next candidate by
    the paired test; the frame's rigidity on top of X's replay is reported (one frame that
    still helps: a tracker error may be present as well). Returns the winner (or None) and the
    report's lines."""
    x = b if a.name == "registration" else a
    if x.tips_full is None:
        return None, []
    TM, TIP, F, H = rows_data
    TX = np.vstack([t[r] for t, r in zip(x.tips_full, rows, strict=True)])
    split = np.linalg.norm(TX - TM, axis=1)
    what = f"how far {x.name} moves the tip"
    alone = frame_rigidity(TM, TIP, F, H, split, noise_mm, TIE_SE)
    lines = ["registration alone: " + alone.line(what)]
    if joint is not None and joint.name == f"{x.name}+registration":
        on_x = frame_rigidity(TX, TIP, F, H, split, noise_mm, TIE_SE)
        lines.append(f"registration on top of {x.name}: " + on_x.line(what))
    if alone.rigid or x.shrink < NAME_SHRINK:
        return None, lines
    rest = [f for f in ranked if f.name not in (x.name, "registration") and "+" not in f.name]
    if rest:
        g, se = _paired_gain(rest[0], x)
        if not g > TIE_SE * se:
            lines.append(
                f"{x.name} against {rest[0].name}: {g:.3g} mm^2 (SE {se:.2g}), not beyond the noise"
            )
            return None, lines
    return x, lines


def nested_test(a: EffectFit, b: EffectFit, joint: EffectFit) -> tuple[EffectFit | None, list[str]]:
    """Whether the log needs ``a`` (the better alone) rather than ``b``, from their joint fit:
    adding ``b`` to ``a`` and adding ``a`` to ``b`` are each judged by the paired held-out test
    (``TIE_SE`` standard errors). ``a`` is named when adding it to ``b`` predicts the held-out
    rows better and adding ``b`` to ``a`` does not, by a smaller mean drop; else nothing
    separates them (None). ``b`` is never named: one addition passing the test and the other
    not, against the ranking alone, says only that their errors scatter differently (the
    difference of the two drops is the tied single-fit difference). Returns the winner and a
    line per addition."""
    g_ab, se_ab = _paired_gain(a, joint)  # b added to a
    g_ba, se_ba = _paired_gain(b, joint)  # a added to b
    helps_b = bool(g_ab > TIE_SE * se_ab)
    helps_a = bool(g_ba > TIE_SE * se_ba)
    lines = [
        f"{b.name} added to {a.name}: {g_ab:.3g} mm^2 (SE {se_ab:.2g}), "
        + ("helps" if helps_b else "adds nothing beyond the noise"),
        f"{a.name} added to {b.name}: {g_ba:.3g} mm^2 (SE {se_ba:.2g}), "
        + ("helps" if helps_a else "adds nothing beyond the noise"),
    ]
    if helps_a and not helps_b and g_ab < g_ba:
        return a, lines
    return None, lines


def _paired_gain(worse: EffectFit, better: EffectFit) -> tuple[float, float]:
    """(mean drop of the held-out squared tip error ``worse`` -> ``better`` (mm^2), its standard
    error from blocks of rows); (nan, nan) when a candidate kept no per-row errors."""
    if worse.err2_heldout is None or better.err2_heldout is None:
        return math.nan, math.nan
    return heldout_gain(worse.err2_heldout, better.err2_heldout)


def _rmse_rows(d: np.ndarray) -> float:
    e = np.sum(d * d, axis=1)
    e = e[np.isfinite(e)]
    return math.sqrt(float(e.mean())) if e.size else math.nan
