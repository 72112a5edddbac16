"""When was the tracker sample in each row taken? A sample-and-hold tracker on its own clock.

Every control cycle the loop logs the newest tracker frame it has. That frame was exposed some
time before the row: the tracker's latency, plus the frame's age (up to one frame period), plus,
in a simulator, the age of the world's last physics step. With a constant-lag model that varying
delay is left in the residual as a timing error of (tip speed) x (delay - mean delay): at 20 mm/s
and a 100 Hz loop beside a 120 Hz tracker about 0.04 mm RMS, more than the noise of a laser
tracker, and no physical effect of the model can remove it.

When the tracker's clock and the loop's clock run at a fixed ratio (the simulated rig; a tracker
triggered by, or locked to, the controller) the delay is periodic in the cycle number with the beat
period P = f_loop / gcd(f_loop, f_tracker) cycles (100 Hz loop, 120 Hz tracker: P = 5), so the
rows of one beat phase (``cycle mod P``, a *class*) all show the tip the same time ago. This
module estimates that per-class delay from the run itself and applies it to the model's tip.

Estimation (:func:`estimate_timing`), from the residual e = measured - predicted tip of a model
(the controller's, before any effect is fitted):

1. The beat period: for P = 1 .. :data:`MAX_BEAT_ROWS` the residual is regressed on the P
   linearised delay columns -v * [class == c] (v the model's tip velocity, mm/s), after a second
   difference along the rows on both sides: the model's own error is smooth in time and drops
   out, the row-to-row delay pattern stays. Rows near kinks of the model's tip (reversals, stick,
   command steps; :data:`KINK_FACTOR`) are left out: there the linearisation fails. P is chosen
   by BIC (P = 1, a constant delay, unless a period explains clearly more). Clocks that drift
   apart give no period: P = 1, the classic lag.
2. The per-class delays: their differences (mean zero) from the same second-differenced
   regression. Their common part is confounded with the model's error along the path (a missing
   backlash looks like a delay), so :func:`estimate_timing` leaves it at zero. The workflow
   estimates it with the controller's model (:meth:`TipTiming.with_common_delay`, Gauss-Newton
   on the interpolated tip: no linearisation), fits what remains as a linear lag nuisance with
   the effects, and once the best model is known estimates it again with that model for the
   gaps it reports, the same timing before and after.

:meth:`TipTiming.apply` evaluates a tip series at t_i - delay_i by linear interpolation in time
(exact when the delays are whole rows, as when a simulator steps its world once per cycle).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Longest beat period (cycles) searched: 1000 Hz or 250 Hz loop beside a 120 Hz tracker is 25.
MAX_BEAT_ROWS = 32
#: Fewest rows per class for a period to be considered.
MIN_ROWS_PER_CLASS = 30
#: Largest delay accepted (s); a longer one means the fit found something else than timing.
MAX_DELAY_S = 0.25
#: A row is a kink of the model's tip when the model's second difference there (mm, the change
#: of its velocity within one row) exceeds the median size of the residual's second difference
#: (noise and timing, the scale of every row of the regression) times this factor: a reversal,
#: the end of a stick phase, a step of the command. There the linearised delay column -v L is
#: wrong by about (change of v) x L, far above the noise on a fast tip, and on a periodic path
#: it is the same class of rows at every kink, which a longer spurious beat period would fit.
KINK_FACTOR = 1.0
#: Rows within this time of a kink are left out of the delay regression (s): the tracker's
#: delay (latency plus a frame's age, ~5-30 ms) with a margin.
KINK_GUARD_S = 0.04
#: Latency of a tracker's own pipeline (exposure to the frame's arrival) that a log without
#: sample timestamps is granted (s): optical motion capture over NatNet 3-10 ms, laser trackers
#: up to ~15 ms (vendors' figures), with a margin. A common delay beyond this plus one frame
#: and one loop cycle (the ages the log itself shows) has no timing evidence behind it: it is
#: the fit using time as a free knob, e.g. a friction hysteresis mistaken for lag (issue #17).
MAX_TRACKER_LATENCY_S = 0.02


def frame_period_s(t_s: np.ndarray, tip_mm: np.ndarray) -> float:
    """The tracker's frame period as the log shows it (s): the median time between rows whose
    tip value changed (a sample-and-hold port repeats a frame until the next arrives); the
    median row interval when every row changes; nan with fewer than 3 changes."""
    t = np.asarray(t_s, dtype=float)
    tip = np.asarray(tip_mm, dtype=float)
    ok = np.all(np.isfinite(tip), axis=1)
    t, tip = t[ok], tip[ok]
    if t.size < 4:
        return math.nan
    changed = np.any(np.diff(tip, axis=0) != 0, axis=1)
    tc = t[1:][changed]
    if tc.size < 3:
        return math.nan
    return float(np.median(np.diff(tc)))


def delay_bound_s(t_s: np.ndarray, tip_mm: np.ndarray) -> float:
    """Largest common tracker delay the log's timing can support (s): the tracker pipeline's
    latency (:data:`MAX_TRACKER_LATENCY_S`) + one tracker frame (the held frame's age, from
    :func:`frame_period_s`) + one row (the row's own age). :data:`MAX_DELAY_S` when the log
    shows no frame period."""
    frame = frame_period_s(t_s, tip_mm)
    rows = np.diff(np.asarray(t_s, dtype=float))
    row = float(np.median(rows)) if rows.size else 0.0
    if not math.isfinite(frame):
        return MAX_DELAY_S
    return min(MAX_DELAY_S, MAX_TRACKER_LATENCY_S + frame + row)


@dataclass(frozen=True)
class TipTiming:
    """Delay of the tracker sample behind each row.

    ``period_rows`` P (1: one constant delay), ``delay_s`` (P,) per class, ``classes`` (N,) the
    class of each row (cycle number mod P), ``t_s`` (N,) the row times. ``note``: how it was found.
    """

    period_rows: int
    delay_s: np.ndarray
    classes: np.ndarray
    t_s: np.ndarray
    note: str = ""
    suspect: str = ""

    @property
    def row_delay_s(self) -> np.ndarray:
        """(N,) delay of every row (s)."""
        return self.delay_s[self.classes]

    def apply(self, tip_mm: np.ndarray) -> np.ndarray:
        """The model tip series (N, 3) as the tracker shows it: each row at t_i - delay_i (mm)."""
        return _at(self.t_s - self.row_delay_s, self.t_s, np.asarray(tip_mm, dtype=float))

    def with_common_delay(
        self,
        tip_meas: np.ndarray,
        tip_model: np.ndarray,
        start_s: float = 0.0,
        bound_s: float = MAX_DELAY_S,
    ) -> TipTiming:
        """The same pattern with its common delay fitted to ``tip_model`` (the best model's tip
        at the row times, mm), starting from ``start_s`` (see module doc).

        The delay is bounded to [0, ``bound_s``] (a tracker shows the past, and no further back
        than the log's timing supports, :func:`delay_bound_s`); a fitted delay outside is
        clipped and the timing marked ``suspect``: what it absorbed is left to the physics."""
        rel = self.delay_s - self.delay_s.mean()
        free = _common_delay(self.t_s, tip_meas, tip_model, rel[self.classes], start_s)
        common = float(np.clip(free, 0.0, bound_s))
        suspect = ""
        if free != common:
            suspect = (
                f"the fit wanted a tracker delay of {1e3 * free:.1f} ms, outside the"
                f" [0, {1e3 * bound_s:.1f}] ms the log's timing supports (latency allowance"
                f" + one frame + one row): kept at {1e3 * common:.1f} ms; the rest of that"
                " gap is physics, not lag"
            )
        if self.period_rows == 1:
            note = f"constant tracker delay {1e3 * common:.1f} ms (no beat with the loop)"
        else:
            pattern = ", ".join(f"{1e3 * (common + r):.1f}" for r in rel)
            note = (
                f"tracker samples beat with the loop every {self.period_rows} cycles; delay per"
                f" cycle phase [{pattern}] ms"
            )
        if suspect:
            note += f" (SUSPECT: {suspect})"
        return TipTiming(self.period_rows, rel + common, self.classes, self.t_s, note, suspect)


def no_timing(t_s: np.ndarray) -> TipTiming:
    """Zero delay everywhere (the identity)."""
    return TipTiming(1, np.zeros(1), np.zeros(len(t_s), dtype=int), np.asarray(t_s), "none")


def _second_difference(x: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x[i+1] - 2 x[i] + x[i-1] over rows (axis 0) where all three rows are usable."""
    d = x[2:] - 2.0 * x[1:-1] + x[:-2]
    m = ok[2:] & ok[1:-1] & ok[:-2]
    return d, m


def _delay_columns(v: np.ndarray, classes: np.ndarray, P: int) -> np.ndarray:
    """(N, 3, P): the linearised effect of a delay of class c on the tip, -v * [class == c]."""
    cols = np.zeros((*v.shape, P))
    for c in range(P):
        m = classes == c
        cols[m, :, c] = -v[m]
    return cols


def _common_delay(
    t_s: np.ndarray,
    tip_meas: np.ndarray,
    tip_model: np.ndarray,
    rel_delay: np.ndarray,
    start_s: float = 0.0,
) -> float:
    """Common delay (s) that, with the per-row pattern ``rel_delay``, best maps the model to the
    measurement: Gauss-Newton on the interpolated series from ``start_s`` (a few steps, clipped
    to +-:data:`MAX_DELAY_S`), kept only if it lowers the squared error."""
    ok = np.all(np.isfinite(tip_meas), axis=1)
    if ok.sum() < 10:
        return 0.0

    def sse(L: float) -> float:
        pred = _at(t_s - (rel_delay + L), t_s, tip_model)
        return float(np.sum((tip_meas - pred)[ok] ** 2))

    velocity = np.gradient(tip_model, t_s, axis=0)

    L = float(np.clip(start_s, -MAX_DELAY_S, MAX_DELAY_S))
    best = (sse(L), L)
    for _ in range(6):
        tq = t_s - (rel_delay + L)
        pred = _at(tq, t_s, tip_model)
        v = _at(tq, t_s, velocity)
        e = (tip_meas - pred)[ok].ravel()
        a = -v[ok].ravel()
        den = float(a @ a)
        if den <= 0:
            break
        step = float(a @ e) / den
        L = float(np.clip(L + step, -MAX_DELAY_S, MAX_DELAY_S))
        f = sse(L)
        if f < best[0]:
            best = (f, L)
        if abs(step) < 1e-6:
            break
    return best[1]


def _near_kinks(t_s: np.ndarray, model: np.ndarray, scale_mm: float) -> np.ndarray:
    """(N,) rows within :data:`KINK_GUARD_S` of a kink of the model's tip: a row whose second
    difference exceeds :data:`KINK_FACTOR` x ``scale_mm``."""
    n = len(t_s)
    out = np.zeros(n, dtype=bool)
    if n < 3 or not scale_mm > 0:
        return out
    d2 = np.linalg.norm(model[2:] - 2.0 * model[1:-1] + model[:-2], axis=1)
    kinks = t_s[1:-1][d2 > KINK_FACTOR * scale_mm]
    if kinks.size == 0:
        return out
    j = np.searchsorted(kinks, t_s)
    before = np.abs(t_s - kinks[np.clip(j - 1, 0, kinks.size - 1)])
    after = np.abs(kinks[np.clip(j, 0, kinks.size - 1)] - t_s)
    return np.minimum(before, after) <= KINK_GUARD_S


def estimate_timing(
    t_s: np.ndarray,
    cycle: np.ndarray,
    tip_meas_mm: np.ndarray,
    tip_model_mm: np.ndarray,
    max_period: int = MAX_BEAT_ROWS,
) -> TipTiming:
    """Beat period and per-class delays of the tracker samples (see module doc).

    ``cycle`` (N,) the loop's cycle number of each row (integers; the row index when the log has
    none), ``tip_meas_mm`` (N, 3) measured (NaN where untracked), ``tip_model_mm`` (N, 3) a
    model's tip at the row times (mm). Never raises: without a usable tip it returns zero delay.
    """
    t_s = np.asarray(t_s, dtype=float)
    cycle = np.asarray(cycle, dtype=np.int64)
    meas = np.asarray(tip_meas_mm, dtype=float)
    model = np.asarray(tip_model_mm, dtype=float)
    ok = np.all(np.isfinite(meas), axis=1)
    if ok.sum() < 3 * MIN_ROWS_PER_CLASS or len(t_s) < 4:
        return no_timing(t_s)
    v = np.gradient(model, t_s, axis=0)
    e = np.where(ok[:, None], meas - model, 0.0)
    # consecutive cycles only: a dropped row breaks the second difference
    consecutive = np.ones(len(t_s), dtype=bool)
    consecutive[1:] &= np.diff(cycle) == 1
    consecutive[:-1] &= np.diff(cycle) == 1
    ok2 = ok & consecutive
    de, m = _second_difference(e, ok2)
    if m.any():
        scale = float(np.median(np.linalg.norm(de[m], axis=1)))
        m &= ~_near_kinks(t_s, model, scale)[1:-1]
    y = de[m].ravel()
    n = y.size
    if n < 3 * MIN_ROWS_PER_CLASS:
        return no_timing(t_s)
    best = None
    for P in range(1, max_period + 1):
        classes = np.mod(cycle, P)
        if np.bincount(classes[ok2], minlength=P).min() < MIN_ROWS_PER_CLASS:
            break
        cols = _delay_columns(v, classes, P)
        dA, _ = _second_difference(cols, ok2)
        A = dA[m].reshape(-1, P)
        x, *_ = np.linalg.lstsq(A, y, rcond=None)
        sse = float(np.sum((y - A @ x) ** 2))
        bic = n * math.log(max(sse / n, 1e-300)) + P * math.log(n)
        if best is None or bic < best[0]:
            best = (bic, P, x, sse)
    assert best is not None
    _, P, x, sse = best
    classes = np.mod(cycle, P)
    rel = x - x.mean()
    if P > 1 and (np.max(np.abs(rel)) > MAX_DELAY_S or not np.all(np.isfinite(rel))):
        P, classes, rel = 1, np.zeros(len(t_s), dtype=int), np.zeros(1)
    if P == 1:
        note = "no beat between tracker and loop: one constant tracker delay"
    else:
        pattern = ", ".join(f"{1e3 * r:+.1f}" for r in rel)
        note = (
            f"tracker samples beat with the loop every {P} cycles; delay per cycle phase"
            f" [{pattern}] ms about the common delay"
        )
    return TipTiming(P, rel, classes, t_s, note)


def _at(tq: np.ndarray, t_s: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Series ``x`` (N, C) sampled at ``t_s`` (s), linearly interpolated at the times ``tq``."""
    return np.column_stack([np.interp(tq, t_s, x[:, c]) for c in range(x.shape[1])])
