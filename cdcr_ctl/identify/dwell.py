"""Quasi-static data from a logged sweep: one averaged point per dwell, with its friction state.

A *dwell* is a stretch of the log where the commanded pose (every segment's bending vector
x = θ (cos φ, sin φ), rad) does not change for at least ``min_dwell_s``. The first ``settle_s``
of it are dropped (drive following error, tracker latency, load-cell filter) and the rest is
averaged: drive feedback q_act (mm), load-cell tensions (N), tracker tip (mm, robot base frame).
The standard error of each mean is the sample standard deviation over the square root of the
number of *distinct* readings (the loop logs a sensor's latest value every cycle, so a 120 Hz
tracker read by a 250 Hz loop repeats values; repeats carry no new information).

Friction state (Qi et al. 2023 eq. 17-19 with memory, :mod:`cdcr_ctl.model.shared.friction`): the
mobilised fraction s_k of cable k is +1 while it is pulled in and -1 while it is paid out. The
direction is taken from the change of the commanded ideal displacement q_nominal_k since the
previous dwell (the material crossing the base hole moves the same way for an uncompensated or
compensated sweep: the stretch only lags the geometry). A point's state is *unknown* (the fit
estimates s in [-1, 1]) at the first dwell of a run (history unknown) and after a reversal until
the cable has certainly turned; it is *known* when the cable kept its direction since the previous
dwell and, at that previous dwell, the drive had already come back from the reversal by at least
the cable's play b_k (lost motion between drive and cable, :mod:`cdcr_ctl.model.shared.deadzone`):
the drive crosses the gap of width b_k before it moves the cable, so only from there on does the
cable slide the new way over a whole step between dwells. With b_k = 0 this is "from the second
dwell after a reversal"; with a play wider than the sweep's step several dwells stay unknown. The
drive travel is the logged drive position (``q_act``; the command where the log has no feedback).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.reader import Run

#: Default hold dropped at the start of each dwell before averaging (s).
SETTLE_S = 0.3
#: Shortest constant-command stretch taken as a dwell (s).
MIN_DWELL_S = 0.5
#: Commanded bending vectors closer than this (rad) count as the same pose.
POSE_TOL_RAD = 1e-9
#: Smaller changes of q_nominal between dwells (mm) do not decide a direction.
DIRECTION_EPS_MM = 1e-4


@dataclass(frozen=True)
class DwellPoint:
    """Averages over one dwell (NaN where the log has no such column or no finite sample).

    ``psi_cmd`` (S, 2) rad; ``q_*_mm`` (K,) mm pulled in; ``tension_N`` (K,) N at the load
    cells; ``tip_mm`` (3,) robot base frame. ``*_se`` are standard errors of those means.
    ``s`` (K,) friction direction per cable (+1 pulled in, -1 paid out, 0 never moved) and
    ``s_known`` (K,) whether that state is certain (module docstring).
    """

    run: str
    index: int
    t_start_s: float
    t_end_s: float
    n_samples: int
    psi_cmd: np.ndarray
    q_nominal_mm: np.ndarray
    q_cmd_mm: np.ndarray
    q_act_mm: np.ndarray
    q_act_se_mm: np.ndarray
    tension_N: np.ndarray
    tension_se_N: np.ndarray
    tip_mm: np.ndarray
    tip_se_mm: float
    s: tuple[float, ...] = ()
    s_known: tuple[bool, ...] = ()

    @property
    def n_cables(self) -> int:
        return int(self.q_nominal_mm.size)

    @property
    def has_tip(self) -> bool:
        return bool(np.all(np.isfinite(self.tip_mm)))


def _n_distinct(col: np.ndarray) -> int:
    """Number of runs of equal consecutive finite values (>= 1 when any value is finite)."""
    v = col[np.isfinite(col)]
    if v.size == 0:
        return 0
    return int(1 + np.count_nonzero(np.diff(v) != 0.0))


def _mean_se(block: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column means and standard errors of an (n, m) block, ignoring NaN."""
    m = block.shape[1]
    mean = np.full(m, math.nan)
    se = np.full(m, math.nan)
    for j in range(m):
        col = block[:, j]
        ok = np.isfinite(col)
        if not ok.any():
            continue
        mean[j] = float(np.mean(col[ok]))
        n_eff = _n_distinct(col)
        sd = float(np.std(col[ok], ddof=1)) if ok.sum() > 1 else 0.0
        se[j] = sd / math.sqrt(max(n_eff, 1))
    return mean, se


def _dwell_ranges(t: np.ndarray, x: np.ndarray, min_dwell_s: float, tol: float):
    """(first, last) row indices of the stretches of constant command lasting >= min_dwell_s."""
    N = t.size
    if N == 0:
        return []
    flat = x.reshape(N, -1)
    change = np.any(np.abs(np.diff(flat, axis=0)) > tol, axis=1)
    starts = np.concatenate(([0], np.flatnonzero(change) + 1))
    ends = np.concatenate((starts[1:] - 1, [N - 1]))
    return [
        (int(a), int(b)) for a, b in zip(starts, ends, strict=True) if t[b] - t[a] >= min_dwell_s
    ]


def extract_dwells(
    run: Run,
    settle_s: float = SETTLE_S,
    min_dwell_s: float = MIN_DWELL_S,
    tol_rad: float = POSE_TOL_RAD,
) -> tuple[list[DwellPoint], list[str]]:
    """Dwell points of one run (in time order) with their friction states, and warnings.

    Needs the commanded pose columns; drive feedback falls back to the sent command (warned),
    tensions and tip are NaN when the log has none. Raises :class:`RigError` naming the file
    when the log has no pose columns or no dwell.
    """
    warnings: list[str] = []
    if not run.has("psi_cmd"):
        raise RigError(f"{run.samples_path}: no commanded pose columns; cannot find dwells")
    t = run.t_s
    psi = run.psi_cmd()
    x = np.stack((psi[..., 0] * np.cos(psi[..., 1]), psi[..., 0] * np.sin(psi[..., 1])), -1)
    K = run.n_cables
    nan_k = np.full((len(run), K), math.nan)
    q_nom = run.q_nominal() if run.has("q_nominal") else nan_k
    q_cmd = run.q_cmd() if run.has("q_cmd") else nan_k
    if run.has("q_act"):
        q_act = run.q_act()
    else:
        q_act = q_cmd
        warnings.append(f"{run.samples_path}: no drive feedback; using the sent command as q_act")
    if not run.has("q_nominal"):
        warnings.append(f"{run.samples_path}: no q_nominal; friction directions from q_cmd")
        q_nom = q_cmd
    tension = run.tension() if run.has("tension") else nan_k
    tip = run.tip() if run.has("tip") else np.full((len(run), 3), math.nan)
    points: list[DwellPoint] = []
    for a, b in _dwell_ranges(t, x, min_dwell_s, tol_rad):
        rows = np.arange(a, b + 1)
        rows = rows[t[rows] >= t[a] + settle_s]
        if rows.size == 0:
            continue
        qa, qa_se = _mean_se(q_act[rows])
        T, T_se = _mean_se(tension[rows])
        p, p_se = _mean_se(tip[rows])
        points.append(
            DwellPoint(
                run=run.run_dir.name,
                index=len(points),
                t_start_s=float(t[a]),
                t_end_s=float(t[b]),
                n_samples=int(rows.size),
                psi_cmd=psi[a].copy(),
                q_nominal_mm=np.nanmean(q_nom[rows], axis=0)
                if np.isfinite(q_nom[rows]).any()
                else np.full(K, math.nan),
                q_cmd_mm=_mean_se(q_cmd[rows])[0],
                q_act_mm=qa,
                q_act_se_mm=np.nan_to_num(qa_se, nan=0.0),
                tension_N=T,
                tension_se_N=np.nan_to_num(T_se, nan=0.0),
                tip_mm=p,
                tip_se_mm=float(np.sqrt(np.nanmean(p_se**2))) if np.isfinite(p_se).any() else 0.0,
            )
        )
    if not points:
        raise RigError(
            f"{run.samples_path}: no dwell of >= {min_dwell_s} s at a constant commanded pose"
        )
    return assign_friction_states(points), warnings


def assign_friction_states(
    points: list[DwellPoint],
    eps_mm: float = DIRECTION_EPS_MM,
    play_mm: Sequence[float] | None = None,
) -> list[DwellPoint]:
    """Fill ``s`` and ``s_known`` of consecutive points of one run (module docstring).

    ``play_mm``: per cable, the play b_k (mm) the drive crosses after a reversal before the
    cable turns (None: no play)."""
    out: list[DwellPoint] = []
    K = points[0].n_cables
    play = [0.0] * K if play_mm is None else [max(float(b), 0.0) for b in play_mm]
    direction = [0.0] * K
    known = [False] * K
    turned = [0.0] * K  # drive position at the last reversal, per cable
    prev = None
    for p in points:
        px_all = _drive_mm(prev) if prev is not None else None
        for k in range(K):
            dq = 0.0 if prev is None else float(p.q_nominal_mm[k] - prev.q_nominal_mm[k])
            if not math.isfinite(dq) or abs(dq) <= eps_mm:
                continue  # no motion: the state (and its certainty) is kept
            new = 1.0 if dq > 0 else -1.0
            px = float(px_all[k]) if px_all is not None else math.nan
            if new != direction[k]:
                turned[k] = px  # the previous dwell is the reversal's extreme
                known[k] = False
            else:
                # past the gap at the previous dwell: the cable slid the new way since then
                travel = new * (px - turned[k])
                known[k] = not (travel < play[k]) if play[k] > 0 else True
            direction[k] = new
        out.append(replace(p, s=tuple(direction), s_known=tuple(known)))
        prev = p
    return out


def _drive_mm(p: DwellPoint) -> np.ndarray:
    """The drive position of a point (mm): feedback, else the command, else q_nominal."""
    x = np.where(np.isfinite(p.q_act_mm), p.q_act_mm, p.q_cmd_mm)
    return np.where(np.isfinite(x), x, p.q_nominal_mm)


def with_play(points: Sequence[DwellPoint], play_mm: Sequence[float]) -> list[DwellPoint]:
    """``points`` (one or more runs, each in time order) with their friction states assigned
    for the cables' play ``play_mm`` (:func:`assign_friction_states`, run by run)."""
    out: list[DwellPoint] = []
    i = 0
    pts = list(points)
    while i < len(pts):
        j = i
        while j < len(pts) and pts[j].run == pts[i].run:
            j += 1
        out += assign_friction_states(pts[i:j], play_mm=play_mm)
        i = j
    return out
