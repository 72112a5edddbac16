"""Trajectories: timed setpoints of segment bend θ_i and bending direction φ_i (rad).

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

Files
-----
CSV: comment lines start with ``#``; header ``t_s,seg1_theta_rad,seg1_phi_rad,seg2_theta_rad,...``
(exactly these names, segments in order); one row per sample.

YAML::

    name: demo            # optional
    n_segments: 1         # optional; checked against the rows and the rig
    samples:              # a list of samples (the whole file may also be just this list)
      - t_s: 0.0
        segments: [[0.0, 0.0]]        # [theta_rad, phi_rad] per segment, base to tip
      - {t_s: 5.0, segments: [[1.5708, 0.0]]}

Both are validated: times finite, >= 0 and strictly increasing; θ, φ finite, θ >= 0; segment
count equal to the rig's; θ within the bend limit; bending-vector rate within the rate limit.
Errors are :class:`~cdcr_ctl.errors.ConfigError` naming the file, the line and the column/field.
"""

from __future__ import annotations

import bisect
import math
import numbers
import re
from collections.abc import Callable, Mapping, Sequence
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
        if t.size <= LIST_SAMPLES:
            self._tl, self._xl, self._pl = t.tolist(), self._x.tolist(), p.tolist()
        else:
            # A long trajectory (a 10^6-row file) stays in its arrays: making millions of Python
            # floats would hold the interpreter for seconds, in the loop's process. sample() then
            # bisects and steps on numpy scalars (the same float64 arithmetic, ~10 us a call).
            self._tl, self._xl, self._pl = t, self._x, p

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
        for (a0, b0), (a1, b1), (th0, ph0), (_, ph1) in zip(
            self._xl[k], self._xl[k + 1], self._pl[k], self._pl[k + 1], strict=True
        ):
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
                    f"time must increase (previous sample at {t[n - 1]!r} s)",
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


# =========================================================================== loaders
def _sample_locator(n: int, i: int, what: str) -> str:
    if i < 0:
        return f"samples[{n}]" + (".t_s" if what == "t" else "")
    return f"samples[{n}].seg{i + 1}_{what}"


def _rows_locator(n: int, i: int, what: str) -> str:
    j = 0 if i < 0 else 2 * i + 1 + (what == "phi")
    return f"samples[{n}]" if what == "segments" else f"samples[{n}][{j}]"


def _float(value: Any) -> float | None:
    """A finite-or-not float from a real number (not a bool); None for anything else."""
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        return None
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def from_samples(
    samples: Sequence[Sequence[float]],
    n_segments: int | None = None,
    bend_limit_rad: float | Sequence[float] | None = None,
    max_rate_rad_s: float | Sequence[float] | None = None,
    source: str = "samples",
    name: str = "",
) -> Trajectory:
    """Trajectory from rows ``[t_s, seg1_theta, seg1_phi, ...]`` (the daemon's request form).

    Errors name ``source`` and ``samples[n][j]``.
    """
    if isinstance(samples, np.ndarray):
        samples = samples.tolist()
    if not isinstance(samples, Sequence) or isinstance(samples, str | bytes) or not samples:
        raise ConfigError(source, "samples", "need a non-empty list of samples")
    width = None
    values: list[list[float]] = []
    for n, row in enumerate(samples):
        if not isinstance(row, Sequence) or isinstance(row, str | bytes):
            raise ConfigError(source, f"samples[{n}]", "a sample is a list [t_s, theta, phi, ...]")
        if width is None:
            width = len(row)
            if width < 3 or width % 2 == 0:
                raise ConfigError(
                    source,
                    f"samples[{n}]",
                    f"{width} values: need t_s then (theta, phi) per segment",
                    width,
                )
        if len(row) != width:
            raise ConfigError(source, f"samples[{n}]", f"{len(row)} values, the first had {width}")
        vals = []
        for j, v in enumerate(row):
            f = _float(v)
            if f is None or not math.isfinite(f):
                raise ConfigError(source, f"samples[{n}][{j}]", "not a finite number", v)
            vals.append(f)
        values.append(vals)
    arr = np.array(values)
    traj = Trajectory(
        arr[:, 0], arr[:, 1:].reshape(len(arr), -1, 2), name, source, locate=_rows_locator
    )
    return traj.validate(n_segments, bend_limit_rad, max_rate_rad_s)


def load_trajectory(
    path: str | Path,
    n_segments: int | None = None,
    bend_limit_rad: float | Sequence[float] | None = None,
    max_rate_rad_s: float | Sequence[float] | None = None,
) -> Trajectory:
    """Load a ``.csv`` or ``.yaml``/``.yml`` trajectory file and validate it (module docstring)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".csv":
        return load_csv(p, n_segments, bend_limit_rad, max_rate_rad_s)
    if suffix in (".yaml", ".yml"):
        return load_yaml(p, n_segments, bend_limit_rad, max_rate_rad_s)
    raise ConfigError(str(p), "", "trajectory files are .csv, .yaml or .yml")


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(str(path), "", f"cannot read: {exc.strerror or exc}") from exc
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ConfigError(str(path), f"line {line}", "not UTF-8 text") from exc


_CSV_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$", re.ASCII)


def load_csv(
    path: str | Path,
    n_segments: int | None = None,
    bend_limit_rad: float | Sequence[float] | None = None,
    max_rate_rad_s: float | Sequence[float] | None = None,
) -> Trajectory:
    """Load a CSV trajectory (header ``t_s,seg1_theta_rad,seg1_phi_rad,...``) and validate it.

    Errors are :class:`ConfigError` with key ``line L, <column>``.
    """
    p = Path(path)
    src = str(p)
    text = _read_text(p)
    header: list[str] | None = None
    values: list[list[float]] = []
    lines: list[int] = []
    for ln, raw in enumerate(text.split("\n"), start=1):
        line = raw.rstrip("\r").strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        if header is None:
            header = _csv_header(src, ln, fields)
            continue
        if len(fields) != len(header):
            raise ConfigError(src, f"line {ln}", f"{len(fields)} fields for {len(header)} columns")
        row = []
        for name, field in zip(header, fields, strict=True):
            if not _CSV_NUMBER.match(field):
                raise ConfigError(src, f"line {ln}, {name}", "not a number", field)
            row.append(float(field))
        values.append(row)
        lines.append(ln)
    if header is None:
        raise ConfigError(src, "", "no header line (t_s,seg1_theta_rad,seg1_phi_rad,...)")
    if not values:
        raise ConfigError(src, "", "no samples after the header")
    arr = np.array(values)

    def locate(n: int, i: int, what: str) -> str:
        if what == "segments":
            return "header"
        col = "t_s" if i < 0 else f"seg{i + 1}_{what}_rad"
        return f"line {lines[n]}, {col}"

    traj = Trajectory(arr[:, 0], arr[:, 1:].reshape(len(arr), -1, 2), p.stem, src, locate)
    return traj.validate(n_segments, bend_limit_rad, max_rate_rad_s)


def _csv_header(src: str, ln: int, fields: list[str]) -> list[str]:
    if len(fields) < 3 or len(fields) % 2 == 0:
        raise ConfigError(
            src,
            f"line {ln}",
            "header must be t_s then seg{i}_theta_rad, seg{i}_phi_rad per segment",
            ",".join(fields)[:200],
        )
    expected = ["t_s"]
    for i in range(1, (len(fields) - 1) // 2 + 1):
        expected += [f"seg{i}_theta_rad", f"seg{i}_phi_rad"]
    for j, (got, want) in enumerate(zip(fields, expected, strict=True), start=1):
        if got != want:
            raise ConfigError(src, f"line {ln}, column {j}", f"expected {want!r}", got[:200])
    return expected


def _yaml_node_line(node: Any, path: Sequence[str | int]) -> int | None:
    """1-based line of the YAML node at ``path`` (keys and indices), or of its deepest parent."""
    line = node.start_mark.line + 1
    for part in path:
        nxt = None
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                if isinstance(k, yaml.ScalarNode) and k.value == str(part):
                    nxt = v
                    break
        elif (
            isinstance(node, yaml.SequenceNode)
            and isinstance(part, int)
            and 0 <= part < len(node.value)
        ):
            nxt = node.value[part]
        if nxt is None:
            return line
        node = nxt
        line = node.start_mark.line + 1
    return line


def load_yaml(
    path: str | Path,
    n_segments: int | None = None,
    bend_limit_rad: float | Sequence[float] | None = None,
    max_rate_rad_s: float | Sequence[float] | None = None,
) -> Trajectory:
    """Load a YAML trajectory (module docstring) and validate it.

    Errors are :class:`ConfigError` with key ``samples[n].segments[i][0] (line L)``.
    """
    p = Path(path)
    src = str(p)
    text = _read_text(p)
    loader = None
    try:
        loader = yaml.SafeLoader(text)
        root = loader.get_single_node()
        doc = loader.construct_document(root) if root is not None else None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(src, where, f"YAML syntax error: {problem}") from exc
    except RecursionError as exc:
        raise ConfigError(src, "", "YAML nested too deeply") from exc
    finally:
        if loader is not None:
            loader.dispose()

    def key(path_: Sequence[str | int]) -> str:
        text_ = ""
        for part in path_:
            text_ += f"[{part}]" if isinstance(part, int) else ("." if text_ else "") + part
        line = _yaml_node_line(root, path_) if root is not None else None
        return f"{text_} (line {line})" if line else text_

    name = p.stem
    base: list[str | int] = []
    declared: int | None = None
    if isinstance(doc, Mapping):
        for k in doc:
            if k not in ("name", "n_segments", "samples"):
                raise ConfigError(src, key([str(k)]), "unknown key (name, n_segments, samples)")
        if "name" in doc:
            if not isinstance(doc["name"], str):
                raise ConfigError(src, key(["name"]), "must be text", doc["name"])
            name = doc["name"]
        if "n_segments" in doc:
            declared = doc["n_segments"]
            if isinstance(declared, bool) or not isinstance(declared, int) or declared < 1:
                raise ConfigError(src, key(["n_segments"]), "must be an integer >= 1", declared)
        if "samples" not in doc:
            raise ConfigError(src, "samples", "missing")
        samples = doc["samples"]
        base = ["samples"]
    else:
        samples = doc
    if not isinstance(samples, list) or not samples:
        raise ConfigError(src, key(base) or "samples", "need a non-empty list of samples")

    S = declared
    ts: list[float] = []
    psis: list[list[list[float]]] = []
    for n, item in enumerate(samples):
        here: list[str | int] = [*base, n]
        if not isinstance(item, Mapping):
            raise ConfigError(src, key(here), "a sample is {t_s: ..., segments: [[theta, phi]]}")
        for k in item:
            if k not in ("t_s", "segments"):
                raise ConfigError(src, key([*here, str(k)]), "unknown key (t_s, segments)")
        if "t_s" not in item or "segments" not in item:
            raise ConfigError(src, key(here), "needs t_s and segments")
        t = _float(item["t_s"])
        if t is None or not math.isfinite(t):
            raise ConfigError(src, key([*here, "t_s"]), "not a finite number", item["t_s"])
        segs = item["segments"]
        if not isinstance(segs, list) or not segs:
            raise ConfigError(
                src, key([*here, "segments"]), "need a list of [theta_rad, phi_rad] per segment"
            )
        if S is None:
            S = len(segs)
        if len(segs) != S:
            what = "n_segments" if declared is not None else "the first sample"
            raise ConfigError(
                src, key([*here, "segments"]), f"{len(segs)} segment(s), {what} says {S}"
            )
        row = []
        for i, pair in enumerate(segs):
            if not isinstance(pair, list) or len(pair) != 2:
                raise ConfigError(
                    src, key([*here, "segments", i]), "a segment is [theta_rad, phi_rad]"
                )
            vals = []
            for j, v in enumerate(pair):
                f = _float(v)
                if f is None or not math.isfinite(f):
                    raise ConfigError(src, key([*here, "segments", i, j]), "not a finite number", v)
                vals.append(f)
            row.append(vals)
        ts.append(t)
        psis.append(row)

    def locate(n: int, i: int, what: str) -> str:
        if what == "segments":
            return key([*base, n, "segments"])
        if i < 0:
            return key([*base, n, "t_s"])
        return key([*base, n, "segments", i, 0 if what == "theta" else 1])

    traj = Trajectory(ts, psis, name, src, locate)
    return traj.validate(n_segments, bend_limit_rad, max_rate_rad_s)


# =========================================================================== built-ins
def _grid(duration_s: float, dt_s: float) -> np.ndarray:
    """0, dt, 2 dt, ..., duration (the last step may be shorter)."""
    if not dt_s > 0:
        raise RigError(f"dt_s must be > 0, got {dt_s!r}")
    n = max(1, math.ceil(duration_s / dt_s - 1e-6))
    t = np.arange(n + 1) * dt_s
    t[-1] = duration_s
    return t


def _positive(value: float | Sequence[float], S: int, name: str, allow_zero: bool) -> np.ndarray:
    arr = _per_segment(value, S, name)
    if np.any(arr < 0) or (not allow_zero and np.any(arr == 0)):
        raise RigError(f"{name}: must be {'>=' if allow_zero else '>'} 0, got {arr.tolist()}")
    return arr


def planar_bend(
    n_segments: int = 1,
    theta_max_rad: float | Sequence[float] = math.pi / 2,
    rate_rad_s: float | Sequence[float] = QI2023_BEND_RATE_RAD_S,
    phi_rad: float | Sequence[float] = 0.0,
    back: bool = False,
    hold_s: float = 0.0,
) -> Trajectory:
    """Planar bending of Qi et al. 2023 §5.1: in the plane φ = β = 0, θ from 0 to 90° at π/10
    rad/s (5 s); with ``back``, hold ``hold_s`` and return to straight at the same rate.

    Per segment (scalar or one value per segment): ``theta_max_rad`` (0 keeps a segment
    straight), ``rate_rad_s``, ``phi_rad``. All segments start together; each holds its
    θ_max until the slowest arrives. θ is piecewise linear, so the samples are just the
    breakpoints (exact under the bending-vector interpolation since φ is constant).
    """
    S = n_segments
    th = _positive(theta_max_rad, S, "theta_max_rad", allow_zero=True)
    rate = _positive(rate_rad_s, S, "rate_rad_s", allow_zero=False)
    phi = _per_segment(phi_rad, S, "phi_rad")
    if hold_s < 0 or not math.isfinite(hold_s):
        raise RigError(f"hold_s: must be >= 0, got {hold_s!r}")
    up = th / rate
    T_up = float(up.max())
    if T_up <= 0:
        raise RigError("theta_max_rad: at least one segment must bend")
    knots = {0.0, T_up, *up.tolist()}
    if back:
        T_down0 = T_up + hold_s
        knots |= {T_down0, *(T_down0 + up).tolist()}
    t = np.array(sorted(knots))

    def theta_at(tq: np.ndarray) -> np.ndarray:
        rise = np.minimum(rate[None, :] * tq[:, None], th[None, :])
        if not back:
            return rise
        fall = th[None, :] - rate[None, :] * np.maximum(tq[:, None] - (T_up + hold_s), 0.0)
        return np.clip(np.minimum(rise, fall), 0.0, None)

    theta = theta_at(t)
    psi = np.stack((theta, np.broadcast_to(phi, theta.shape)), axis=-1)
    name = "planar_bend_back" if back else "planar_bend"
    return Trajectory(t, psi, name, f"<builtin {name}>")


def go_and_return(
    n_segments: int = 1,
    theta_max_rad: float | Sequence[float] = math.pi / 2,
    rate_rad_s: float | Sequence[float] = QI2023_BEND_RATE_RAD_S,
    phi_rad: float | Sequence[float] = 0.0,
    hold_s: float = 0.0,
) -> Trajectory:
    """0 -> θ_max -> 0 in the plane φ at constant rate, holding ``hold_s`` at θ_max (per-segment
    parameters as in :func:`planar_bend`)."""
    traj = planar_bend(n_segments, theta_max_rad, rate_rad_s, phi_rad, back=True, hold_s=hold_s)
    return Trajectory(traj.t_s, traj.psi, "go_and_return", "<builtin go_and_return>")


def _smooth_ramp(u: np.ndarray) -> np.ndarray:
    """(1 - cos πu)/2 on [0, 1], clipped: 0 -> 1 with zero slope at both ends; peak slope π/2."""
    return 0.5 * (1.0 - np.cos(math.pi * np.clip(u, 0.0, 1.0)))


def spatial_circle(
    n_segments: int = 1,
    theta_rad: float | Sequence[float] = math.pi / 4,
    phi_rate_rad_s: float | Sequence[float] = QI2023_BEND_RATE_RAD_S,
    turns: float = 1.0,
    phi0_rad: float | Sequence[float] = 0.0,
    lead_in_rate_rad_s: float | Sequence[float] = QI2023_BEND_RATE_RAD_S,
    lead_out: bool = True,
    dt_s: float = BUILTIN_DT_S,
) -> Trajectory:
    """Spatial circle after Qi et al. 2023 §5.2: fixed bend θ, direction φ sweeping ``turns``
    full turns at ``phi_rate_rad_s`` (tip on a circle about the base axis).

    The paper states neither θ nor the sweep rate of §5.2: the defaults (θ = 45°, π/10 rad/s,
    i.e. one turn in 20 s) are ours. Lead-in from straight: θ rises along a raised cosine at φ0
    with peak rate ``lead_in_rate_rad_s`` (duration π θ / (2 rate)), zero rate at both ends; the
    sweep starts when every segment is at θ. ``lead_out`` returns to straight the same way.
    Per-segment values are scalars or one per segment (a segment with θ = 0 stays straight;
    give ``phi_rate_rad_s`` negative to sweep clockwise).
    """
    S = n_segments
    th = _positive(theta_rad, S, "theta_rad", allow_zero=True)
    rate = _per_segment(phi_rate_rad_s, S, "phi_rate_rad_s")
    phi0 = _per_segment(phi0_rad, S, "phi0_rad")
    lead = _positive(lead_in_rate_rad_s, S, "lead_in_rate_rad_s", allow_zero=False)
    if not (math.isfinite(turns) and turns > 0):
        raise RigError(f"turns: must be > 0, got {turns!r}")
    if not np.any(th > 0) or np.any((th > 0) & (rate == 0)):
        raise RigError("theta_rad and phi_rate_rad_s: bent segments need a non-zero sweep rate")
    T_in_i = math.pi * th / (2 * lead)
    T_in = float(T_in_i.max())
    sweep = 2 * math.pi * turns
    T_sweep = float(np.max(np.where(th > 0, sweep / np.abs(np.where(rate == 0, 1, rate)), 0)))
    T = T_in + T_sweep + (T_in if lead_out else 0.0)
    # Sample the lead-in and lead-out at dt, the sweep at dt, and always their boundaries.
    t = np.unique(
        np.concatenate(
            (
                _grid(T_in, dt_s),
                T_in + _grid(T_sweep, dt_s),
                T_in + T_sweep + _grid(T - T_in - T_sweep, dt_s),
            )
        )
    )
    tt = t[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        u_in = np.where(T_in_i > 0, tt / T_in_i, 1.0)
        theta = th * _smooth_ramp(u_in)
        if lead_out:
            u_out = np.where(T_in_i > 0, (T - tt) / T_in_i, 1.0)
            theta = np.minimum(theta, th * _smooth_ramp(u_out))
    sweep_t = np.clip(tt - T_in, 0.0, T_sweep)
    phi = phi0 + np.sign(rate) * np.minimum(np.abs(rate) * sweep_t, sweep)
    psi = np.stack((theta, np.broadcast_to(phi, theta.shape)), axis=-1)
    return Trajectory(t, psi, "spatial_circle", "<builtin spatial_circle>")


def move(
    start: np.ndarray | Sequence[Any],
    goal: np.ndarray | Sequence[Any],
    speed_rad_s: float = LEAD_IN_SPEED_RAD_S,
    dt_s: float = BUILTIN_DT_S,
) -> Trajectory:
    """Smooth move from ``start`` to ``goal`` ((S, 2) rows (θ, φ), rad) in the bending vectors:
    x(t) = x0 + (x1 - x0)(1 - cos(π t/T))/2, zero rate at both ends, peak rate ``speed_rad_s``
    for the segment that moves furthest (T = π max|Δx| / (2 speed)). Start == goal gives a
    one-sample trajectory (duration 0)."""
    p0 = np.asarray(start, dtype=float).reshape(-1, 2)
    p1 = np.asarray(goal, dtype=float).reshape(-1, 2)
    if p0.shape != p1.shape:
        raise RigError(f"move: start has {len(p0)} segment(s), goal {len(p1)}")
    if not (math.isfinite(speed_rad_s) and speed_rad_s > 0):
        raise RigError(f"speed_rad_s: must be > 0, got {speed_rad_s!r}")
    x0, x1 = bend_vectors(p0), bend_vectors(p1)
    dist = float(np.max(np.linalg.norm(x1 - x0, axis=-1)))
    if dist == 0.0:
        return Trajectory([0.0], p1[None], "move", "<move>")
    T = math.pi * dist / (2 * speed_rad_s)
    t = _grid(T, dt_s)
    s = _smooth_ramp(t / T)[:, None, None]
    x = x0[None] + s * (x1 - x0)[None]
    # φ of straight samples from the goal (then the start): the direction being moved along.
    hint = np.where(p1[:, 0] > 0, p1[:, 1], p0[:, 1])
    psi = psi_from_vectors(x, phi_start=np.where(p0[:, 0] > 0, p0[:, 1], hint))
    psi[0], psi[-1] = p0, p1
    return Trajectory(t, psi, "move", "<move>")


def with_lead_in(
    psi_now: np.ndarray | Sequence[Any],
    traj: Trajectory,
    speed_rad_s: float = LEAD_IN_SPEED_RAD_S,
    tolerance_rad: float = 1e-6,
) -> Trajectory:
    """``traj`` preceded by a smooth :func:`move` from ``psi_now`` to its first sample, unless
    they are within ``tolerance_rad`` (bending-vector distance). Times shift by the move's
    duration; name and source stay ``traj``'s."""
    p_now = np.asarray(psi_now, dtype=float).reshape(-1, 2)
    if p_now.shape[0] != traj.n_segments:
        raise RigError(
            f"lead-in: robot has {p_now.shape[0]} segment(s), trajectory "
            f"{traj.name!r} {traj.n_segments}"
        )
    gap = np.linalg.norm(bend_vectors(p_now) - traj.x[0], axis=-1)
    if float(gap.max()) <= tolerance_rad:
        return traj
    m = move(p_now, traj.psi[0], speed_rad_s)
    later = traj.t_s + m.duration_s
    keep = m.n_samples if later[0] > m.t_s[-1] else m.n_samples - 1  # traj may hold first
    t = np.concatenate((m.t_s[:keep], later))
    psi = np.concatenate((m.psi[:keep], traj.psi))
    return Trajectory(t, psi, traj.name, traj.source)


def random_smooth(
    n_segments: int,
    duration_s: float,
    bend_limit_rad: float | Sequence[float],
    max_rate_rad_s: float | Sequence[float],
    seed: int,
    bandwidth_hz: float = 0.2,
    margin: float = 0.9,
    dt_s: float = BUILTIN_DT_S,
) -> Trajectory:
    """A seeded random smooth trajectory within limits, for soak tests.

    Each segment's bending vector is a sum of 6 sinusoids per axis with random amplitudes,
    phases and frequencies up to ``bandwidth_hz``, windowed by raised cosines (2 s or a quarter
    of the run) so it starts and ends straight at rest, then scaled so the samples stay within
    ``margin`` x the bend limit and ``margin`` x the rate limit (both per segment or one for
    all). The same seed gives the same trajectory.
    """
    S = n_segments
    lim = _positive(bend_limit_rad, S, "bend_limit_rad", allow_zero=False)
    rate = _positive(max_rate_rad_s, S, "max_rate_rad_s", allow_zero=False)
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise RigError(f"duration_s: must be > 0, got {duration_s!r}")
    if not (0 < margin <= 1) or not bandwidth_hz > 0:
        raise RigError("margin must be in (0, 1] and bandwidth_hz > 0")
    rng = np.random.default_rng(seed)
    t = _grid(duration_s, dt_s)
    ramp = min(2.0, duration_s / 4)
    w = _smooth_ramp(t / ramp) * _smooth_ramp((duration_s - t) / ramp)
    M = 6
    x = np.zeros((t.size, S, 2))
    for i in range(S):
        for ax in range(2):
            f = rng.uniform(0.2, 1.0, M) * bandwidth_hz
            a = rng.normal(0.0, 1.0, M) / np.arange(1, M + 1)
            ph = rng.uniform(0, 2 * math.pi, M)
            x[:, i, ax] = w * np.sin(2 * math.pi * f[None, :] * t[:, None] + ph).dot(a)
    peak = np.linalg.norm(x, axis=-1).max(axis=0)
    speed = (np.linalg.norm(np.diff(x, axis=0), axis=-1) / np.diff(t)[:, None]).max(axis=0)
    with np.errstate(divide="ignore"):
        scale = margin * np.minimum(lim / peak, rate / speed)
    scale = np.where(np.isfinite(scale), scale, 0.0)
    x *= scale[None, :, None]
    psi = psi_from_vectors(x)
    psi[0, :, 0] = 0.0
    psi[-1, :, 0] = 0.0
    return Trajectory(t, psi, f"random_smooth_seed{seed}", f"<builtin random_smooth seed={seed}>")


#: Built-in trajectories by name (for the CLI).
BUILTINS: dict[str, Callable[..., Trajectory]] = {
    "planar_bend": planar_bend,
    "spatial_circle": spatial_circle,
    "go_and_return": go_and_return,
    "random_smooth": random_smooth,
}
