"""Hole-angle offsets per segment from tendon-pull runs (one cable pulled at a time).

Geometry (Qi et al. 2023 eq. 1-4, constant curvature; :mod:`cdcr_ctl.model.cc_disk.params`): every
disk frame carries no net twist, so a cable keeps one hole angle gamma_k in every disk it passes.
Pulling cable k alone (the others held) bends every segment it crosses in the plane of its hole,
phi = gamma_k: the moment T_k r_k (cos gamma_k, sin gamma_k) is the only one out of symmetry,
and the held cables of each segment (a pattern turned with the same offset) answer in the same
plane. The tip of a chain of arcs in one plane through the z axis lies in that plane, so the
azimuth of the tip's displacement from the straight pose, atan2(dy, dx), is gamma_k. The
measured azimuth minus the config's hole angle is the segment's hole offset, model-free (no
stiffness, friction or routing radius needed). The cables of other segments, carrying only
pretension, bend the plane by a fraction of a degree at most (simulated: see the tests).

:func:`hole_offsets_from_pulls` takes the rows where exactly one cable is displaced by more than
``min_pull_mm`` and the tip moved by more than ``min_tip_mm``; each gives one azimuth residual,
weighted by the tip displacement (the tracker noise over the displacement is the angle noise).
The offset of segment i is the weighted circular mean over the rows of its cables; its 95 %
interval comes from the weighted scatter of the residuals (Student t, one degree of freedom per
pulled cable fewer: rows within one pull are not independent).

Misfit: the tracker noise sigma per axis is bounded from the scatter of the rest rows (all
cables at 0; hysteresis only adds), so a row's azimuth noise is sigma / rho. The scatter of the
residuals about the segment's offset in those units (``misfit_ratio``, RMS of dev rho / sigma)
is about 1 when one offset per segment explains the pulls; far above (``identify`` refuses above
5, :mod:`.keypoint_gate`) the cables of a segment do not bend in one common plane turned by one
offset: holes off by different angles, twist, or a model that does not hold.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import t as student_t

from cdcr_ctl.errors import RigError
from cdcr_ctl.model.cc_disk.params import RobotParams
from cdcr_ctl.runlog.reader import Run, load_run

#: A cable counts as pulled beyond this displacement (mm); the others must stay within
#: REST_TOL_MM of their rest position.
MIN_PULL_MM = 0.5
REST_TOL_MM = 0.05
#: Rows whose tip moved less than this from the straight pose (mm) give no azimuth.
MIN_TIP_MM = 2.0


@dataclass(frozen=True)
class HoleOffset:
    """Fitted hole-angle offset of one segment (rad), its 95 % interval, and the support."""

    segment: str
    offset_rad: float
    ci95_rad: tuple[float, float]
    n_rows: int
    cables: tuple[str, ...]
    misfit_ratio: float = float("nan")  # azimuth scatter / what the tracker noise explains


def pull_rows(q: np.ndarray) -> np.ndarray:
    """Per row the pulled cable (index) or -1 (none or several displaced from rest = 0)."""
    moved = np.abs(q) > REST_TOL_MM
    one = moved.sum(axis=1) == 1
    k = np.argmax(np.abs(q), axis=1)
    big = np.abs(q[np.arange(len(q)), k]) > MIN_PULL_MM
    return np.where(one & big, k, -1)


def is_pull_log(run: Run) -> bool:
    """Whether most moving rows of ``run`` displace exactly one cable (a tendon-pull run)."""
    if not run.has("q_act"):
        return False
    q = run.q_act()
    q = q[np.all(np.isfinite(q), axis=1)]
    moving = np.any(np.abs(q) > REST_TOL_MM, axis=1)
    return bool(moving.sum() >= 3 and (pull_rows(q) >= 0).sum() >= 0.8 * moving.sum())


def hole_offsets_from_pulls(
    params: RobotParams, run_dirs: Sequence[str | Path]
) -> tuple[list[HoleOffset], list[str]]:
    """Hole offset per segment from the pull runs (module docstring), and warnings."""
    warnings: list[str] = []
    per_seg: dict[int, list[tuple[float, float, int]]] = {}
    noise_sq: list[float] = []
    for rd in run_dirs:
        run = load_run(rd)
        warnings += run.warnings
        if not (run.has("q_act") and run.has("tip")):
            raise RigError(f"{run.samples_path}: a pull run needs actuator and tip columns")
        q, tip = run.q_act(), run.tip()
        if q.shape[1] != params.n_cables:
            raise RigError(
                f"{run.samples_path}: {q.shape[1]} cables logged, the config has {params.n_cables}"
            )
        ok = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(tip), axis=1)
        rest = ok & ~np.any(np.abs(np.nan_to_num(q)) > REST_TOL_MM, axis=1)
        if not rest.any():
            raise RigError(f"{run.samples_path}: no row at rest (all cables at 0) for the origin")
        tip0 = np.mean(tip[rest], axis=0)
        if rest.sum() >= 3:  # rest rows scatter: noise plus hysteresis, an upper bound
            noise_sq.append(float(np.mean(np.var(tip[rest][:, :2], axis=0, ddof=1))))
        who = pull_rows(np.nan_to_num(q))
        for i in np.flatnonzero(ok & (who >= 0)):
            k = int(who[i])
            d = tip[i, :2] - tip0[:2]
            rho = float(np.hypot(d[0], d[1]))
            if rho < MIN_TIP_MM:
                continue
            c = params.cables[k]
            # a cable paid out (q < 0) goes slack: no bend in its plane; pulled: azimuth = gamma
            if q[i, k] < 0:
                continue
            res = math.atan2(d[1], d[0]) - c.hole_angle_rad
            res = math.atan2(math.sin(res), math.cos(res))
            per_seg.setdefault(c.segment, []).append((res, rho, k))
    out: list[HoleOffset] = []
    sigma = math.sqrt(float(np.mean(noise_sq))) if noise_sq else math.nan
    for i, seg in enumerate(params.segments):
        rows = per_seg.get(i, [])
        if not rows:
            warnings.append(f"{seg.name}: no pull of its cables moved the tip; offset not fitted")
            continue
        a = np.array([r[0] for r in rows])
        w = np.array([r[1] for r in rows]) ** 2  # angle variance ~ (noise / rho)^2
        mean = math.atan2(float(np.sum(w * np.sin(a))), float(np.sum(w * np.cos(a))))
        dev = np.arctan2(np.sin(a - mean), np.cos(a - mean))
        cables = sorted({r[2] for r in rows})
        n_eff = max(len(cables), 2)
        sd = math.sqrt(float(np.sum(w * dev**2) / np.sum(w)))
        half = float(student_t.ppf(0.975, n_eff - 1)) * sd / math.sqrt(n_eff)
        rho = np.array([r[1] for r in rows])
        # the azimuth noise of a row is sigma / rho (rad): the scatter in those units
        ratio = math.sqrt(float(np.mean((dev * rho / sigma) ** 2))) if sigma > 0 else math.nan
        out.append(
            HoleOffset(
                seg.name,
                mean,
                (mean - half, mean + half),
                len(rows),
                tuple(params.cables[k].name for k in cables),
                ratio,
            )
        )
    return out, warnings


def offsets_lines(offsets: Sequence[HoleOffset]) -> list[str]:
    """Plain-text table of the fitted offsets (degrees)."""
    out = ["hole-angle offsets from tendon pulls (tip azimuth minus config hole angle):"]
    for h in offsets:
        lo, hi = (math.degrees(v) for v in h.ci95_rad)
        out.append(
            f"  {h.segment:<8} {math.degrees(h.offset_rad):+8.3f} deg  95 % CI [{lo:+.3f}, "
            f"{hi:+.3f}]  from {h.n_rows} rows of {', '.join(h.cables)}; azimuth scatter "
            f"{h.misfit_ratio:.3g} x the tracker noise"
        )
    return out
