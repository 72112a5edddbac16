"""What kind of log a run is, and its quasi-static points for each kind.

Three kinds of log reach identification:

* ``loadcell``: the daemon's calibration sweep: commanded poses held in dwells, load-cell
  tensions, tracker tip, drive feedback. Points are dwell averages (:mod:`.dwell`).
* ``tip``: commanded poses held in dwells, tracker tip and drive feedback, no load cell.
  Points are dwell averages too; only tip-observable parameters can be fitted.
* ``keypoint``: rows seconds apart (quasi-static keypoints), no commanded pose: the pose is
  whatever the actuators reached. Every row with a tip is a point; there is no dwell to find.

:func:`detect_kind` decides from the columns and the timing: no commanded-pose columns, or a
median row spacing of at least :data:`KEYPOINT_MIN_DT_S`, means keypoints; otherwise tensions
mean ``loadcell`` and their absence ``tip``. A flag may impose the kind instead.

Keypoint friction states (Qi et al. 2023 eq. 17-19 with memory): the direction of each cable is
the sign of its *measured actuator* displacement since the previous row (:func:`keypoint_points`),
known when it kept its direction, unknown at a reversal (the fit estimates s in [-1, 1] there).
"""

from __future__ import annotations

import math

import numpy as np

from cdcr_ctl.errors import RigError
from cdcr_ctl.identify.dwell import DwellPoint, assign_friction_states
from cdcr_ctl.runlog.reader import Run

KINDS = ("loadcell", "tip", "keypoint")
#: Median row spacing (s) from which a log counts as quasi-static keypoints (a control loop
#: logs every 1-10 ms; the labs' keypoint logs are ~0.5 s apart).
KEYPOINT_MIN_DT_S = 0.1
#: Actuator moves smaller than this (mm) between keypoints decide no direction (a few counts
#: of a 1238.6 counts/mm drive).
KEYPOINT_DIRECTION_EPS_MM = 0.005


def detect_kind(run: Run) -> tuple[str, str]:
    """(kind, why) for ``run``; :class:`RigError` naming the file when nothing fits."""
    if not run.has("tip"):
        raise RigError(f"{run.samples_path}: no tracker tip columns; nothing to identify from")
    if not (run.has("q_act") or run.has("q_cmd")):
        raise RigError(f"{run.samples_path}: no actuator position columns (cableK_q_act_mm)")
    dt = float(np.median(np.diff(run.t_s))) if len(run) > 1 else math.inf
    if not run.has("psi_cmd"):
        return "keypoint", "no commanded pose columns: each row is a quasi-static keypoint"
    if dt >= KEYPOINT_MIN_DT_S:
        return "keypoint", f"rows {dt:.3g} s apart (>= {KEYPOINT_MIN_DT_S} s): keypoints"
    if run.has("tension"):
        return "loadcell", f"dwells of commanded poses, load cells, rows {dt * 1e3:.3g} ms apart"
    return "tip", f"dwells of commanded poses, no load cells, rows {dt * 1e3:.3g} ms apart"


def keypoint_points(run: Run, n_segments: int) -> tuple[list[DwellPoint], np.ndarray, list[str]]:
    """One point per row with a finite tip and actuator positions, in time order.

    Returns the points, the full actuator path (N, K) mm (for a forward replay that keeps the
    friction memory of every row) and warnings. ``DwellPoint.index`` is the row number.
    """
    warnings: list[str] = []
    K, S = run.n_cables, n_segments  # a log without pose columns does not know S
    if run.has("q_act"):
        q = run.q_act()
    else:
        q = run.q_cmd()
        warnings.append(f"{run.samples_path}: no drive feedback; using the sent command as q_act")
    tip = run.tip()
    tension = run.tension() if run.has("tension") else np.full((len(run), K), math.nan)
    psi = run.psi_cmd() if run.has("psi_cmd") else np.full((len(run), S, 2), math.nan)
    t = run.t_s
    ok = np.all(np.isfinite(tip), axis=1) & np.all(np.isfinite(q), axis=1)
    if not ok.any():
        raise RigError(f"{run.samples_path}: no row with both a tip and actuator positions")
    if (~ok).any():
        warnings.append(f"{run.samples_path}: {int((~ok).sum())} rows without tip or q skipped")
    pts: list[DwellPoint] = []
    zeros = np.zeros(K)
    for i in np.flatnonzero(ok):
        pts.append(
            DwellPoint(
                run=run.run_dir.name,
                index=int(i),
                t_start_s=float(t[i]),
                t_end_s=float(t[i]),
                n_samples=1,
                psi_cmd=psi[i].copy(),
                q_nominal_mm=q[i].copy(),  # directions from the actuator path
                q_cmd_mm=np.full(K, math.nan),
                q_act_mm=q[i].copy(),
                q_act_se_mm=zeros,
                tension_N=tension[i].copy(),
                tension_se_N=zeros,
                tip_mm=tip[i].copy(),
                tip_se_mm=0.0,
            )
        )
    return assign_friction_states(pts, KEYPOINT_DIRECTION_EPS_MM), q, warnings


def split_by_time(
    points: list[DwellPoint], holdout_fraction: float
) -> tuple[list[DwellPoint], list[DwellPoint]]:
    """(fit, held out): per run, the last ``holdout_fraction`` of its time span is held out."""
    fit: list[DwellPoint] = []
    held: list[DwellPoint] = []
    runs: dict[str, list[DwellPoint]] = {}
    for p in points:
        runs.setdefault(p.run, []).append(p)
    for pts in runs.values():
        t0, t1 = pts[0].t_start_s, pts[-1].t_end_s
        cut = t1 - holdout_fraction * (t1 - t0)
        fit += [p for p in pts if p.t_end_s < cut]
        held += [p for p in pts if p.t_end_s >= cut]
    return fit, held
