"""The trajectory itself: timed setpoints of segment bend θ_i and bending direction φ_i (rad),
their validation, and sampling/interpolation in the bending vector (Qi et al. 2023 §2).

A :class:`Trajectory` is N samples ``(t_s[n], psi[n])`` with ``psi[n]`` of shape (S, 2): rows
(θ_i, φ_i) for segments i = 1..S from base to tip, θ_i >= 0 the bend angle, φ_i the direction of
the bending plane about the segment's z axis (Qi et al. 2023 §2; the paper calls it β in §5).
It is a :class:`~cdcr_ctl.control.ports.SetpointSource`: the loop calls :meth:`Trajectory.sample`
at the cycle time.

Interpolation (documented choice): between two samples each segment moves linearly in its
*bending vector* x = θ (cos φ, sin φ) (rad); θ = |x| and φ = atan2(x) are taken from it.

- θ = 0 needs no special case: x = 0 is the straight pose whatever φ says, and a move from
  straight to (θ, φ) keeps direction φ all the way (φ of a straight sample is irrelevant; φ of the
  straight pose is reported from the neighbouring sample).
- φ wraps: 350° -> 10° moves 20° through 0°, never 340° back round.
- When φ is constant between two samples, θ is exactly linear in time (the planar bend and the
  go-and-return are exact). The speed of x is constant between samples, so the rate limit checked
  on the samples (|Δx|/Δt, rad/s) is the exact peak rate of the interpolated path.
- Cost: a sweep in φ at constant θ follows the chord between samples, whose θ dips by
  θ (1 - cos(Δφ/2)) mid-way (1e-4 θ at Δφ = 1.6°). Give sweeps densely; the built-ins sample
  every :data:`BUILTIN_DT_S`.

φ is reported on the branch of the interval's left sample (φ_left + wrap(atan2(x) - φ_left)), so a
file that unwraps φ (0 -> 2π for a full turn) gets unwrapped φ back.
Before the first sample time the first setpoint holds; after the last, the last one holds;
:attr:`Trajectory.duration_s` is the last sample time.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from cdcr_ctl.errors import ConfigError, RigError

#: Spacing of the samples of the built-in trajectories (s).
BUILTIN_DT_S = 0.01
#: Bending rate of Qi et al. 2023 §5.1: π/10 rad/s (0 -> 90° in 5 s).
QI2023_BEND_RATE_RAD_S = math.pi / 10
#: Default speed of lead-in moves from the current pose to a trajectory's first sample (rad/s,
#: peak of the bending vector's speed).
#: Trajectories up to this many samples keep plain-list copies for :meth:`Trajectory.sample`.
LIST_SAMPLES = 50_000
LEAD_IN_SPEED_RAD_S = math.pi / 10
#: Relative slack on the rate check (samples computed exactly at the limit pass).
_RATE_RTOL = 1e-9

# where(sample index, segment index 0-based or -1 for time, "t"|"theta"|"phi") -> key text
Locator = Callable[[int, int, str], str]


def _wrap(a: np.ndarray | float) -> Any:
    """Angle to [-π, π)."""
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


def bend_vectors(psi: np.ndarray) -> np.ndarray:
    """x = θ (cos φ, sin φ) for (..., 2) arrays of (θ, φ); rad."""
    psi = np.asarray(psi, dtype=float)
    th, ph = psi[..., 0], psi[..., 1]
    return np.stack((th * np.cos(ph), th * np.sin(ph)), axis=-1)


def psi_from_vectors(x: np.ndarray, phi_start: np.ndarray | None = None) -> np.ndarray:
    """(N, S, 2) bending vectors -> (N, S, 2) (θ >= 0, φ) with φ continuous (unwrapped) in n.

    Where θ = 0 (straight) φ repeats the previous φ; leading straight samples take the first φ of
    a bent sample, or ``phi_start`` (S,) if the segment never bends.
    """
    x = np.asarray(x, dtype=float)
    theta = np.hypot(x[..., 0], x[..., 1])
    phi = np.arctan2(x[..., 1], x[..., 0])
    N, S = theta.shape
    for i in range(S):
        bent = np.flatnonzero(theta[:, i] > 0.0)
        if bent.size == 0:
            phi[:, i] = 0.0 if phi_start is None else phi_start[i]
            continue
        # Fill straight samples with the last bent direction (the first one before any).
        idx = np.maximum.accumulate(np.where(theta[:, i] > 0.0, np.arange(N), -1))
        idx = np.where(idx < 0, bent[0], idx)
        col = np.unwrap(phi[idx, i])
        if phi_start is not None:
            col += 2 * math.pi * round((phi_start[i] - col[0]) / (2 * math.pi))
        phi[:, i] = col
    return np.stack((theta, phi), axis=-1)


#: Values converted to Python floats per ``tolist`` call (see :func:`_tolist`).
TOLIST_SLICE = 8192


def _tolist(a: np.ndarray) -> list[Any]:
    """``a.tolist()`` of a 1-D array, :data:`TOLIST_SLICE` values at a time: one ``tolist`` of
    a long array is one C call that keeps the interpreter lock throughout, and trajectories are
    made in the loop's process while the loop runs (issue #21); between two slices the loop
    thread gets the lock back. The same list as ``a.tolist()``."""
    if len(a) <= TOLIST_SLICE:
        return a.tolist()
    out: list[Any] = []
    for i in range(0, len(a), TOLIST_SLICE):
        out.extend(a[i : i + TOLIST_SLICE].tolist())
    return out


class Trajectory:
    """Timed setpoints (see the module docstring for interpolation and file formats).

    ``t_s``: (N,) s, strictly increasing, >= 0. ``psi``: (N, S, 2) rows (θ, φ) in rad.
    The arrays are copied and made read-only. Shape errors raise ``ValueError``; content checks
    are in :meth:`validate` (the loaders call it).
    """

    def __init__(
        self,
        t_s: Sequence[float] | np.ndarray,
        psi: Sequence[Any] | np.ndarray,
        name: str = "",
        source: str = "",
        locate: Locator | None = None,
    ) -> None:
        t = np.array(t_s, dtype=float).reshape(-1)
        p = np.array(psi, dtype=float)
        if p.ndim == 2 and p.shape[1] == 2:
            p = p[:, None, :]
        if t.size < 1 or p.ndim != 3 or p.shape[0] != t.size or p.shape[2] != 2 or p.shape[1] < 1:
            raise ValueError(f"t_s (N,) and psi (N, S, 2) do not fit: {t.shape}, {p.shape}")
        t.flags.writeable = False
        p.flags.writeable = False
        self.t_s = t
        self.psi = p
        self.name = name
        self.source = source or "<trajectory>"
        self._locate = locate or _sample_locator
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite input: validate() says
            self._x = bend_vectors(p)
        self._x.flags.writeable = False
        # sample() reads the bending vectors and poses as flat sequences: sample k, segment j,
        # component c at (k * S + j) * 2 + c. Flat lists of floats hold no container objects
        # for the garbage collector to traverse (nested lists made one per sample and segment,
        # and a collection pass over 10^5 of them held the interpreter for 10-30 ms, in the
        # loop's process: issue #21).
        self._S2 = 2 * p.shape[1]
        if t.size <= LIST_SAMPLES:
            self._tl, self._xl, self._pl = (
                _tolist(t),
                _tolist(self._x.reshape(-1)),
                _tolist(p.reshape(-1)),
            )
        else:
            # A long trajectory (a 10^6-row file) stays in its arrays: making millions of Python
            # floats would hold the interpreter for seconds, in the loop's process. sample() then
            # bisects and steps on numpy scalars (the same float64 arithmetic, ~10 us a call).
            self._tl, self._xl, self._pl = t, self._x.reshape(-1), p.reshape(-1)

    # ------------------------------------------------------------------ properties
    @property
    def n_samples(self) -> int:
        return int(self.t_s.size)

    @property
    def n_segments(self) -> int:
        return int(self.psi.shape[1])

    @property
    def duration_s(self) -> float:
        """Time of the last sample (s); the run ends there."""
        return float(self._tl[-1])

    @property
    def x(self) -> np.ndarray:
        """Bending vectors of the samples, (N, S, 2), rad."""
        return self._x

    def __repr__(self) -> str:
        return (
            f"Trajectory({self.name!r}, {self.n_samples} samples, {self.n_segments} segment(s),"
            f" {self.duration_s:.3f} s)"
        )

    # ------------------------------------------------------------------ sampling
    def sample(self, t_s: float) -> np.ndarray:
        """Setpoint at time ``t_s`` (s): (S, 2) rows (θ, φ) in rad.

        On the loop's path: a bisection and, per segment, one linear step in the bending vector
        in plain floats (a few µs for a few segments).
        """
        tl = self._tl
        if not t_s > tl[0]:  # also NaN
            return self.psi[0].copy()
        if t_s >= tl[-1]:
            return self.psi[-1].copy()
        k = bisect.bisect_right(tl, t_s) - 1
        s = (t_s - tl[k]) / (tl[k + 1] - tl[k])
        if s == 0.0:
            return self.psi[k].copy()
        out = []
        xl, pl, S2 = self._xl, self._pl, self._S2
        i0 = k * S2
        for i in range(i0, i0 + S2, 2):
            a0, b0, a1, b1 = xl[i], xl[i + 1], xl[i + S2], xl[i + S2 + 1]
            th0, ph0, ph1 = pl[i], pl[i + 1], pl[i + S2 + 1]
            xa, xb = a0 + s * (a1 - a0), b0 + s * (b1 - b0)
            theta = math.hypot(xa, xb)
            if theta == 0.0:
                phi = ph0 if s < 0.5 else ph1
            else:
                ref = ph0 if th0 > 0.0 else ph1
                phi = ref + (math.atan2(xb, xa) - ref + math.pi) % (2 * math.pi) - math.pi
            out.append((theta, phi))
        return np.array(out)

    def sample_many(self, t_s: Sequence[float] | np.ndarray) -> np.ndarray:
        """Setpoints at each time of ``t_s``: (M, S, 2), rad (vectorised :meth:`sample`)."""
        tq = np.asarray(t_s, dtype=float).reshape(-1)
        N = self.n_samples
        if N == 1:
            return np.repeat(self.psi[:1], tq.size, axis=0)
        tc = np.clip(np.nan_to_num(tq, nan=self._tl[0]), self._tl[0], self._tl[-1])
        k = np.clip(np.searchsorted(self.t_s, tc, side="right") - 1, 0, N - 2)
        s = ((tc - self.t_s[k]) / (self.t_s[k + 1] - self.t_s[k]))[:, None]  # (M, 1)
        x0, x1 = self._x[k], self._x[k + 1]  # (M, S, 2)
        x = x0 + s[..., None] * (x1 - x0)
        theta = np.hypot(x[..., 0], x[..., 1])
        p0, p1 = self.psi[k], self.psi[k + 1]
        ref = np.where(p0[..., 0] > 0.0, p0[..., 1], p1[..., 1])
        phi = ref + _wrap(np.arctan2(x[..., 1], x[..., 0]) - ref)
        phi = np.where(theta == 0.0, np.where(s < 0.5, p0[..., 1], p1[..., 1]), phi)
        out = np.stack((theta, phi), axis=-1)
        at0, at1 = s[:, 0] == 0.0, s[:, 0] == 1.0  # at a sample: its own values, bit for bit
        out[at0] = p0[at0]
        out[at1] = p1[at1]
        return out

    # ------------------------------------------------------------------ checks
    def validate(
        self,
        n_segments: int | None = None,
        bend_limit_rad: float | Sequence[float] | None = None,
        max_rate_rad_s: float | Sequence[float] | None = None,
    ) -> Trajectory:
        """Check the samples; return ``self``. Raises :class:`ConfigError` naming the source, the
        sample (line) and the field.

        Times finite, >= 0, strictly increasing; θ and φ finite, θ >= 0; ``n_segments`` equal to
        the trajectory's; θ_i <= bend limit (per segment or one for all); bending-vector rate
        |x_{n+1} - x_n| / Δt <= rate limit (rad/s, per segment or one for all): the exact peak
        rate of the interpolated path.
        """
        S = self.n_segments
        where = self._locate
        if n_segments is not None and n_segments != S:
            raise ConfigError(
                self.source,
                where(0, -1, "segments"),
                f"trajectory has {S} segment(s), the rig has {n_segments}",
            )
        t, psi = self.t_s, self.psi
        for n in range(self.n_samples):
            if not math.isfinite(t[n]) or t[n] < 0:
                raise ConfigError(
                    self.source, where(n, -1, "t"), "time must be finite and >= 0", float(t[n])
                )
            if n and not t[n] > t[n - 1]:
                raise ConfigError(
                    self.source,
                    where(n, -1, "t"),
                    f"time must increase (previous sample at {float(t[n - 1])!r} s)",
                    float(t[n]),
                )
        bad = ~np.isfinite(psi)
        if bad.any():
            n, i, j = (int(v) for v in np.argwhere(bad)[0])
            raise ConfigError(
                self.source, where(n, i, ("theta", "phi")[j]), "not finite", float(psi[n, i, j])
            )
        neg = psi[..., 0] < 0
        if neg.any():
            n, i = (int(v) for v in np.argwhere(neg)[0])
            raise ConfigError(
                self.source,
                where(n, i, "theta"),
                "bend angle must be >= 0 (bend the other way with phi + pi)",
                float(psi[n, i, 0]),
            )
        if bend_limit_rad is not None:
            lim = _per_segment(bend_limit_rad, S, "bend_limit_rad")
            over = psi[..., 0] > lim[None, :]
            if over.any():
                n, i = (int(v) for v in np.argwhere(over)[0])
                raise ConfigError(
                    self.source,
                    where(n, i, "theta"),
                    f"bend angle above the limit {float(lim[i])!r} rad",
                    float(psi[n, i, 0]),
                )
        if max_rate_rad_s is not None and self.n_samples > 1:
            rate_lim = _per_segment(max_rate_rad_s, S, "max_rate_rad_s")
            rate = np.linalg.norm(np.diff(self._x, axis=0), axis=-1) / np.diff(t)[:, None]
            over = rate > rate_lim[None, :] * (1 + _RATE_RTOL) + 1e-12
            if over.any():
                n, i = (int(v) for v in np.argwhere(over)[0])
                raise ConfigError(
                    self.source,
                    where(n + 1, i, "theta"),
                    f"bending rate {rate[n, i]:.6g} rad/s since the previous sample is above the"
                    f" limit {float(rate_lim[i])!r} rad/s",
                )
        return self

    def max_rate_rad_s(self) -> np.ndarray:
        """Peak bending-vector rate per segment (rad/s), (S,); zeros for one sample."""
        if self.n_samples < 2:
            return np.zeros(self.n_segments)
        rate = np.linalg.norm(np.diff(self._x, axis=0), axis=-1) / np.diff(self.t_s)[:, None]
        return rate.max(axis=0)

    # ------------------------------------------------------------------ conversions
    def shifted(self, dt_s: float) -> Trajectory:
        """The same samples ``dt_s`` later."""
        return Trajectory(self.t_s + dt_s, self.psi, self.name, self.source)

    def rows(self) -> list[list[float]]:
        """``[[t_s, seg1_theta, seg1_phi, ...], ...]``: the daemon's ``trajectory`` samples."""
        flat = np.column_stack((self.t_s, self.psi.reshape(self.n_samples, -1)))
        return flat.tolist()

    def csv_header(self) -> list[str]:
        cols = ["t_s"]
        for i in range(1, self.n_segments + 1):
            cols += [f"seg{i}_theta_rad", f"seg{i}_phi_rad"]
        return cols

    def to_csv_text(self) -> str:
        """The CSV form (exact float text), loadable by :func:`load_csv`."""
        lines = [",".join(self.csv_header())]
        lines += [",".join(repr(float(v)) for v in row) for row in self.rows()]
        return "\n".join(lines) + "\n"

    def to_yaml_text(self) -> str:
        """The YAML form, loadable by :func:`load_yaml`."""
        doc = {
            "name": self.name,
            "n_segments": self.n_segments,
            "samples": [
                {"t_s": float(t), "segments": [[float(a), float(b)] for a, b in p]}
                for t, p in zip(self.t_s, self.psi, strict=True)
            ],
        }
        return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)

    def write(self, path: str | Path) -> Path:
        """Write as ``.csv`` or ``.yaml``/``.yml`` by suffix."""
        p = Path(path)
        text = self.to_csv_text() if p.suffix.lower() == ".csv" else self.to_yaml_text()
        p.write_text(text, encoding="utf-8")
        return p


def _per_segment(value: float | Sequence[float], S: int, name: str) -> np.ndarray:
    """Broadcast a scalar to (S,), or check a per-segment sequence; RigError naming ``name``."""
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.size == 1:
        arr = np.repeat(arr, S)
    if arr.shape != (S,):
        raise RigError(f"{name}: give one value or one per segment ({S}), got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise RigError(f"{name}: must be finite, got {arr.tolist()}")
    return arr


def _sample_locator(n: int, i: int, what: str) -> str:
    if i < 0:
        return f"samples[{n}]" + (".t_s" if what == "t" else "")
    return f"samples[{n}].seg{i + 1}_{what}"
