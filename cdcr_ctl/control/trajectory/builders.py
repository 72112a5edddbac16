"""Built-in trajectories of the papers (Qi et al. 2023 §5.1 planar bend and spatial circle, the
go-and-return), moves and lead-ins between poses, and smooth random paths for soak runs; each is
a pure builder returning a :class:`~cdcr_ctl.control.trajectory.core.Trajectory` sampled every
:data:`~cdcr_ctl.control.trajectory.core.BUILTIN_DT_S`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from cdcr_ctl.control.trajectory.core import (
    BUILTIN_DT_S,
    LEAD_IN_SPEED_RAD_S,
    QI2023_BEND_RATE_RAD_S,
    Trajectory,
    _per_segment,
    bend_vectors,
    psi_from_vectors,
)
from cdcr_ctl.errors import RigError


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
