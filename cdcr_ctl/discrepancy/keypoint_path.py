"""``discrepancy`` on quasi-static keypoint logs (rows ~0.5 s apart, no commanded pose).

The loop-log path (:mod:`.workflow`) finds motion phases and reversals from the commanded pose
and fits the tracker's lag from the tip's motion between 1-10 ms rows. A keypoint log has
neither: every row is settled, so

* reversals come from the *actuator path*: a cable reverses where the sign of its measured
  displacement step changes (steps smaller than
  :data:`~cdcr_ctl.identify.logkind.KEYPOINT_DIRECTION_EPS_MM` decide nothing);
* no lag is fitted: a settled keypoint carries no timing information (a tracker lag shifts
  nothing when the tip does not move), so the report says "not fitted" instead of a number;
* the refit (:func:`cdcr_ctl.identify.keypoints.identify_keypoint_runs`, the forward replay
  of the actuator path fitted to the tips) carries one effect candidate next to the model's
  parameters: a lost motion (play) between drive and cable, shared by every cable. It is
  *named* when the log identifies it and its 95 % interval lies above zero; otherwise the
  report gives the best parametric refit, what the log identifies, and the share of the
  held-out tip error it removes. The fit uses the first ``max_points`` rows of each run (the
  replay must start at the run's start to carry the friction memory); the held-out rows are
  the last 30 % of the run.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import RigError
from cdcr_ctl.identify.fit_types import Estimate
from cdcr_ctl.identify.keypoints import (
    KeypointIdentification,
    KeypointOptions,
    identify_keypoint_runs,
    report_lines,
)
from cdcr_ctl.identify.logkind import KEYPOINT_DIRECTION_EPS_MM, detect_kind
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


def named_play(refit: KeypointIdentification) -> Estimate | None:
    """The fitted lost motion when the log shows one: ``cables.backlash_mm`` identifiable,
    fitted, and its 95 % interval above zero (more play than the config's)."""
    for e in refit.ident.estimates:
        if e.parameter.kind == "backlash" and e.ci95[0] > 0.0 and not e.at_bound:
            return e
    return None


@dataclass
class KeypointDiscrepancy:
    """Outcome of :func:`analyse_keypoints`."""

    verdict: str
    reversals: dict[str, list[int]]
    row_spacing_s: dict[str, float]
    refit: KeypointIdentification
    explained: float  # share of the held-out tip mean square error the refit removes
    elapsed_s: float
    effect: Estimate | None = None  # the named lost motion (:func:`named_play`), if any

    def lines(self) -> list[str]:
        out = [self.verdict]
        for name, rv in self.reversals.items():
            out.append(
                f"{name}: keypoint log, rows {self.row_spacing_s[name]:.3g} s apart; reversals "
                f"per cable from the actuator path: {rv} (total {sum(rv)})"
            )
        out.append("tracker lag: not fitted (settled keypoints carry no timing)")
        out += report_lines(self.refit)
        out.append(f"elapsed {self.elapsed_s:.1f} s")
        return out


def analyse_keypoints(
    cfg: RigConfig, run_dirs: Sequence[str | Path], max_points: int = 40
) -> KeypointDiscrepancy:
    """Reversals, no lag, and the best parametric refit of keypoint logs (module docstring)."""
    t0 = time.monotonic()
    reversals: dict[str, list[int]] = {}
    spacing: dict[str, float] = {}
    for rd in run_dirs:
        run = load_run(rd)
        q = run.q_act() if run.has("q_act") else run.q_cmd()
        reversals[run.run_dir.name] = reversals_from_path(q).tolist()
        spacing[run.run_dir.name] = float(np.median(np.diff(run.t_s))) if len(run) > 1 else math.nan
    refit = identify_keypoint_runs(
        cfg, run_dirs, KeypointOptions(max_points=max_points, kind="keypoint", backlash=True)
    )
    h = refit.heldout
    explained = 1.0 - (h.rmse_fitted / h.rmse_nominal) ** 2 if h.rmse_nominal > 0 else 0.0
    play = named_play(refit)
    params = ", ".join(e.name for e in refit.ident.estimates)
    if play is not None and explained > 0:
        lo, hi = play.ci95
        verdict = (
            f"EFFECT: transmission lost motion (backlash, Yang 2022 eq. 13-17) of "
            f"{play.value:.3g} mm per cable beyond the config's (95 % CI [{lo:.3g}, "
            f"{hi:.3g}] mm); with the refit "
            f"({params}) it explains {100 * explained:.1f} % of the held-out tip error "
            f"({h.rmse_nominal:.4g} -> {h.rmse_fitted:.4g} mm)"
        )
    elif explained > 0:
        verdict = (
            f"NO NAMED EFFECT; best parametric refit ({params}) explains "
            f"{100 * explained:.1f} % of the held-out tip error "
            f"({h.rmse_nominal:.4g} -> {h.rmse_fitted:.4g} mm)"
        )
    else:
        verdict = (
            "NO EFFECT AND NO PARAMETRIC REFIT EXPLAINS THIS: the refit does not improve the "
            f"held-out rows ({h.rmse_nominal:.4g} -> {h.rmse_fitted:.4g} mm)"
        )
    return KeypointDiscrepancy(
        verdict,
        reversals,
        spacing,
        refit,
        explained,
        time.monotonic() - t0,
        play if explained > 0 else None,
    )
