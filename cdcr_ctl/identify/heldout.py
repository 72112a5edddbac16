"""Held-out check of a keypoint fit: the forward replay of every row of a run with given
parameters (:func:`cdcr_ctl.model.cc_disk.forward.replay`, friction memory kept from the run's
start), its squared tip error per point, and the RMSE over the held-out and the other rows.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from cdcr_ctl.identify import replay_fit
from cdcr_ctl.identify.replay_fit import Evaluator
from cdcr_ctl.model.cc_disk.forward import replay
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams


def heldout_errors(
    params: RobotParams,
    effects: Effects,
    runs: Sequence[Any],
    law: FrictionLawShape | None = None,
) -> tuple[list[np.ndarray], list[str]]:
    """Per run, the squared tip error (mm^2) of the forward replay at every point (NaN where
    the replay has no solution), and the rows with no solution; ``law``: the disk friction's
    law (:func:`cdcr_ctl.identify.replay_fit.stepper`)."""
    out: list[np.ndarray] = []
    failed: list[str] = []
    for rdat in runs:
        rep = replay(replay_fit.stepper(params, effects, law), rdat.q_path)
        failed += [f"{rdat.name} row {i}: {why}" for i, why in rep.failed]
        tips = np.array([p.tip_mm for p in rdat.points])
        d = rep.tip_mm[np.asarray(rdat.rows, dtype=int)] - tips
        out.append(np.sum(d * d, axis=1))
    return out, failed


def heldout_rmse(
    params: RobotParams,
    effects: Effects,
    runs: Sequence[Any],
    held: set[tuple[str, int]],
    law: FrictionLawShape | None = None,
) -> tuple[float, float, list[str]]:
    """Tip RMSE (mm) of the forward replay over held-out and over other point rows."""
    errs, failed = heldout_errors(params, effects, runs, law)
    h, o = _split_errors(runs, errs, held)
    return _rms(h), _rms(o), failed


def _split_errors(runs, errs, held) -> tuple[np.ndarray, np.ndarray]:
    e_held: list[float] = []
    e_other: list[float] = []
    for rdat, e in zip(runs, errs, strict=True):
        for p, v in zip(rdat.points, e, strict=True):
            (e_held if (p.run, p.index) in held else e_other).append(float(v))
    return np.array(e_held), np.array(e_other)


def _rms(e: np.ndarray) -> float:
    e = e[np.isfinite(e)]
    return math.sqrt(float(e.mean())) if e.size else math.nan


def _errors_task(args: tuple) -> tuple[tuple[list[np.ndarray], list[str]], float]:
    c0 = time.process_time()
    out = heldout_errors(*args)
    return out, time.process_time() - c0


def _errors_both(ev: Evaluator, plist, effects, runs) -> list:
    """:func:`heldout_errors` for each parameter set, in the evaluator's workers, under the
    friction law of the evaluator's problem; the CPU time of the replays is added to
    ``ev.cpu_s``."""
    tasks = [(p, effects, runs, ev.prob.friction_law) for p in plist]
    ev.n_replays += len(tasks)
    if ev.pool is None:
        outs = [_errors_task(t) for t in tasks]
    else:
        outs = list(ev.pool.map(_errors_task, tasks))
    ev.cpu_s += sum(c for _, c in outs)
    return [o for o, _ in outs]
