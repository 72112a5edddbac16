"""Where the model and the measurements disagree: in time, pose, motion phase, cable, tension.

All tables are RMS of the tip residual (measured - predicted, mm, 3-D norm) per class, with the
number of rows, so a user sees where the gap lives before any effect is fitted:

* ``time``: equal windows of the run;
* ``motion``: ``hold`` (no cable moves faster than ``hold_mm_s``), ``reversal`` (moving, and some
  cable has travelled less than ``reversal_zone_mm`` since it last changed direction; a change
  of direction counts once the cable is ``reversal_eps_mm`` back from its extreme), ``steady``;
* ``theta`` / ``phi``: the model's bend and bending direction of the distal segment (quartiles of
  theta, six 60 degree sectors of phi);
* ``tension``: quartiles of the mean measured (else predicted) cable tension;
* ``cable``: RMS tension residual per cable (N) and the correlation of the tip error with each
  cable's displacement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdcr_ctl.discrepancy.alignment import AlignedRun
from cdcr_ctl.discrepancy.simulate import Prediction


@dataclass(frozen=True)
class Table:
    """One breakdown: class labels, RMS per class (unit), rows per class."""

    title: str
    unit: str
    labels: list[str]
    rms: list[float]
    count: list[int]


def motion_classes(
    q: np.ndarray,
    t: np.ndarray,
    hold_mm_s: float = 0.05,
    reversal_zone_mm: float = 0.6,
    reversal_eps_mm: float = 0.02,
) -> np.ndarray:
    """Per row: 0 hold, 1 steady, 2 reversal (see module doc)."""
    n, K = q.shape
    dt = np.gradient(t)
    speed = np.max(np.abs(np.gradient(q, axis=0)) / np.maximum(dt, 1e-9)[:, None], axis=1)
    since = np.full((n, K), np.inf)
    for k in range(K):
        ext = q[0, k]
        direction = 0
        q_rev = None
        for i in range(n):
            v = q[i, k]
            if (direction >= 0 and v > ext) or (direction <= 0 and v < ext):
                ext = v
            if direction >= 0 and v < ext - reversal_eps_mm:
                if direction > 0:
                    q_rev = ext
                direction, ext = -1, v
            elif direction <= 0 and v > ext + reversal_eps_mm:
                if direction < 0:
                    q_rev = ext
                direction, ext = 1, v
            if q_rev is not None:
                since[i, k] = abs(v - q_rev)
    cls = np.ones(n, dtype=int)
    cls[np.min(since, axis=1) < reversal_zone_mm] = 2
    cls[speed < hold_mm_s] = 0
    return cls


def _table(title, unit, labels, key, err) -> Table:
    rms, cnt = [], []
    for j in range(len(labels)):
        m = (key == j) & np.isfinite(err)
        cnt.append(int(m.sum()))
        rms.append(float(np.sqrt(np.mean(err[m] ** 2))) if m.any() else float("nan"))
    return Table(title, unit, list(labels), rms, cnt)


def localise(run: AlignedRun, pred: Prediction, windows: int = 8) -> list[Table]:
    """The breakdown tables of one run (see module doc)."""
    e = np.linalg.norm(run.tip_mm - pred.tip_mm, axis=1)
    out = []
    edges = np.linspace(run.t_s[0], run.t_s[-1], windows + 1)
    key = np.clip(np.searchsorted(edges, run.t_s, side="right") - 1, 0, windows - 1)
    out.append(
        _table(
            "time window",
            "mm",
            [f"{edges[j]:.0f}-{edges[j + 1]:.0f} s" for j in range(windows)],
            key,
            e,
        )
    )
    mc = motion_classes(run.q_in_mm, run.t_s)
    out.append(_table("motion", "mm", ["hold", "steady", "reversal"], mc, e))
    th = pred.psi[:, -1, 0]
    ph = np.mod(pred.psi[:, -1, 1], 2 * np.pi)
    qs = np.quantile(th, [0.25, 0.5, 0.75])
    key = np.searchsorted(qs, th)
    b = [0.0, *qs.tolist(), float(th.max())]
    out.append(
        _table(
            "bend theta (distal segment)",
            "mm",
            [f"{np.degrees(b[j]):.0f}-{np.degrees(b[j + 1]):.0f} deg" for j in range(4)],
            key,
            e,
        )
    )
    bent = th > max(0.1, float(np.quantile(th, 0.25)))
    key = np.where(bent, (ph // (np.pi / 3)).astype(int), -1)
    out.append(
        _table(
            "bending direction phi (bent rows)",
            "mm",
            [f"{60 * j}-{60 * (j + 1)} deg" for j in range(6)],
            key,
            e,
        )
    )
    T = run.tension_N if run.tension_N is not None else pred.tension_N
    Tm = np.nanmean(T, axis=1)
    qs = np.nanquantile(Tm, [0.25, 0.5, 0.75])
    key = np.searchsorted(qs, Tm)
    b = [float(np.nanmin(Tm)), *qs.tolist(), float(np.nanmax(Tm))]
    src = "measured" if run.tension_N is not None else "model"
    out.append(
        _table(
            f"mean cable tension ({src})",
            "mm",
            [f"{b[j]:.2f}-{b[j + 1]:.2f} N" for j in range(4)],
            key,
            e,
        )
    )
    if run.tension_N is not None:
        eT = run.tension_N - pred.tension_N
        rms = [
            float(np.sqrt(np.nanmean(eT[:, k] ** 2))) if np.isfinite(eT[:, k]).any() else np.nan
            for k in range(run.n_cables)
        ]
        cnt = [int(np.isfinite(eT[:, k]).sum()) for k in range(run.n_cables)]
        names = [c.name for c in run.spec.params.cables]
        out.append(Table("tension residual by cable", "N", names, rms, cnt))
    ok = np.isfinite(e)
    corr = []
    for k in range(run.n_cables):
        qk = np.abs(run.q_in_mm[ok, k])
        corr.append(
            float(np.corrcoef(qk, e[ok])[0, 1]) if qk.std() > 0 and e[ok].std() > 0 else 0.0
        )
    names = [c.name for c in run.spec.params.cables]
    out.append(
        Table(
            "corr(tip error, |cable displacement|)", "1", names, corr, [int(ok.sum())] * len(names)
        )
    )
    return out
