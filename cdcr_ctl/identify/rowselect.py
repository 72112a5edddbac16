"""Which keypoint rows a replay fit uses: rows that span the log, and how long a fit may take.

A keypoint log's first rows are often one kind of move (a lab's calibration set starts with
single-tendon pulls), so a prefix of the log fits one corner of the workspace. Instead the rows
are chosen by farthest-point sampling (Gonzalez 1985: each next row is the one farthest from
every row chosen so far, a 2-approximation of the smallest covering radius) in a feature space
of the actuator positions and the friction state:

    f_i = ( q_i / s_q ,  w_d d_i )

q_i (K,) mm the actuator positions of row i, s_q the RMS spread of q over the candidate rows (one
number, so the cables keep their relative scale), d_i (K,) in {-1, 0, 1} the direction of each
cable's last move (:func:`directions`) and w_d = 0.5: two rows at the same positions but reached
from opposite sides (a reversal, where friction and play differ) are half a spread apart.

The fit replays only what it needs: each chosen row preceded by the row before it in the log
(:func:`replay_path`), so the forward model's friction memory at a chosen row comes from the same
last move as on the rig. :func:`spread` states how well the chosen rows cover the rest: per cable
the range of q chosen vs available, the reversal rows chosen, and the covering radius (the
largest feature distance from any candidate row to its nearest chosen row, in units of s_q).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Weight of the friction state in the feature space (module docstring).
DIRECTION_WEIGHT = 0.5
#: Fewest rows a budget-chosen fit takes: 180 tip residuals for ~10 parameters; on a machine
#: too slow (or too loaded) for them within the budget the fit overruns it instead.
MIN_FIT_ROWS = 60
#: CPU cost of a replayed chosen row in rows of the log's own path: the row before it is often
#: replayed too (:func:`replay_path`) and the step from the last chosen row is larger than the
#: log's. Measured on the 1600-row hard world (2.1 ms per row of its path): 267 chosen rows
#: 2.6, 60 chosen rows 4.6.
CHOSEN_ROW_COST = 3.0
#: Moves smaller than this (mm) keep a cable's last direction.
DIRECTION_EPS_MM = 0.005


def directions(q_path: np.ndarray, eps_mm: float = DIRECTION_EPS_MM) -> np.ndarray:
    """(N, K) sign of each cable's last move larger than ``eps_mm`` (0 before its first)."""
    q = np.asarray(q_path, dtype=float)
    d = np.zeros_like(q)
    cur = np.zeros(q.shape[1])
    for i in range(1, len(q)):
        step = q[i] - q[i - 1]
        cur = np.where(np.abs(step) > eps_mm, np.sign(step), cur)
        d[i] = cur
    return d


def features(q_path: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, float]:
    """Feature vectors (n, 2K) of ``rows`` of the path and the spread s_q (mm)."""
    q = np.asarray(q_path, dtype=float)
    d = directions(q)[rows]
    qr = q[rows]
    s_q = float(np.sqrt(np.mean((qr - qr.mean(0)) ** 2))) or 1.0
    return np.hstack([qr / s_q, DIRECTION_WEIGHT * d]), s_q


def farthest_points(f: np.ndarray, n: int) -> np.ndarray:
    """Indices of ``n`` rows of ``f`` by farthest-point sampling, from the row nearest the mean."""
    m = len(f)
    if n >= m:
        return np.arange(m)
    first = int(np.argmin(np.sum((f - f.mean(0)) ** 2, axis=1)))
    chosen = [first]
    dist = np.sum((f - f[first]) ** 2, axis=1)
    for _ in range(n - 1):
        j = int(np.argmax(dist))
        chosen.append(j)
        dist = np.minimum(dist, np.sum((f - f[j]) ** 2, axis=1))
    return np.sort(np.array(chosen))


@dataclass(frozen=True)
class Spread:
    """How the chosen rows cover the candidates (module docstring)."""

    n_chosen: int
    n_candidates: int
    q_range_chosen: np.ndarray  # (K, 2) mm
    q_range_all: np.ndarray  # (K, 2) mm
    reversals_chosen: int
    reversals_all: int
    covering_radius: float  # in units of s_q
    s_q_mm: float

    def lines(self) -> list[str]:
        lo_c, hi_c = self.q_range_chosen[:, 0], self.q_range_chosen[:, 1]
        lo_a, hi_a = self.q_range_all[:, 0], self.q_range_all[:, 1]
        span = np.where(hi_a > lo_a, (hi_c - lo_c) / np.maximum(hi_a - lo_a, 1e-12), 1.0)
        return [
            f"rows fitted: {self.n_chosen} of {self.n_candidates} before the hold-out cut, "
            f"chosen to span the actuator space and the friction states (farthest-point)",
            f"  spread: each cable's q range covered {100 * float(span.min()):.0f}-"
            f"{100 * float(span.max()):.0f} % (q spread s_q {self.s_q_mm:.3g} mm); rows just "
            f"after a reversal: {self.reversals_chosen} of {self.reversals_all}; every "
            f"candidate row within {self.covering_radius:.2g} s_q of a fitted one",
        ]


def spread(q_path: np.ndarray, candidates: np.ndarray, chosen: np.ndarray) -> Spread:
    """:class:`Spread` of ``chosen`` (indices into ``candidates``, rows of ``q_path``)."""
    q = np.asarray(q_path, dtype=float)
    f, s_q = features(q, candidates)
    fc = f[chosen]
    # covering radius, in blocks to bound the memory
    worst = 0.0
    for a in range(0, len(f), 512):
        d2 = np.sum((f[a : a + 512, None, :] - fc[None, :, :]) ** 2, axis=2)
        worst = max(worst, float(np.sqrt(d2.min(axis=1).max())))
    d = directions(q)
    rev = np.zeros(len(q), bool)
    rev[1:] = np.any((d[1:] * d[:-1]) < 0, axis=1)
    qc, qa = q[candidates[chosen]], q[candidates]
    return Spread(
        len(chosen),
        len(candidates),
        np.column_stack([qc.min(0), qc.max(0)]),
        np.column_stack([qa.min(0), qa.max(0)]),
        int(rev[candidates[chosen]].sum()),
        int(rev[candidates].sum()),
        worst if math.isfinite(worst) else math.nan,
        s_q,
    )


def replay_path(q_path: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(path, positions): the rows to replay from the straight start (row 0), each chosen row
    preceded by the log's row before it when the step from the previously replayed row would
    give some cable another direction than the log's last move; and where the chosen rows sit
    in that path."""
    q = np.asarray(q_path, dtype=float)
    d = directions(q)
    keep = [0]
    for r in np.unique(np.asarray(rows, dtype=int)):
        if r == 0:
            continue
        step = q[r] - q[keep[-1]]
        implied = np.where(np.abs(step) > DIRECTION_EPS_MM, np.sign(step), 0.0)
        if r - 1 > keep[-1] and np.any((d[r] != 0) & (implied != d[r])):
            keep.append(int(r) - 1)
        keep.append(int(r))
    pos = {r: i for i, r in enumerate(keep)}
    return q[keep], np.array([pos[int(r)] for r in np.asarray(rows, dtype=int)], dtype=int)


def rows_for_budget(cpu_budget_s: float, cpu_per_row: float, replays: float) -> int:
    """How many chosen rows a fit of ``replays`` replays of its rows (forward-difference
    Jacobians, sensitivity replays and trial evaluations, counted in plain replays) can replay
    within ``cpu_budget_s`` seconds of CPU time when a row of the log's own path costs
    ``cpu_per_row`` of it (a chosen row costs :data:`CHOSEN_ROW_COST` such rows); at least
    :data:`MIN_FIT_ROWS`. CPU time, not wall time: about the same rows on a loaded machine as
    on an idle one (the loaded one takes longer)."""
    per_row = replays * CHOSEN_ROW_COST * cpu_per_row
    return max(MIN_FIT_ROWS, int(cpu_budget_s / max(per_row, 1e-9)))
