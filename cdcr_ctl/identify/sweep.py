"""The calibration sweep of Qi et al. 2023 §5 (eq. 38, Table 1) as timed setpoints.

The paper bends the robot in the planes β = 0°, 120°, 240° (β is the bending-plane direction,
φ in this project) through θ = 40°-90° in 5° steps and fits the friction of each cable to the
load-cell tensions. Here, per swept segment and per β:

1. from straight, a slow ramp (``approach_rate_rad_s``) to θ_start with dwells every
   ``approach_step_deg`` on the way (the paper starts at 40° but the robot starts straight: the
   ramp is part of the sweep, run slowly, and its dwells are data too);
2. up: θ_start -> θ_stop in ``theta_step_deg`` steps at ``step_rate_rad_s``, dwell at each;
3. down: back to θ_start through the same angles (the other friction direction);
4. a slow return to straight with dwells at the approach angles and at 0.

Every dwell lasts ``dwell_s`` so quasi-static samples can be averaged (the fit drops the first
``settle_s`` of each dwell, see :mod:`cdcr_ctl.identify.dwell`). Between dwells θ moves
linearly at constant φ, which the trajectory's bending-vector interpolation follows exactly.
With several segments each is swept in turn while the others are held straight.

Units: s, rad (degrees only in the names of the spec fields that say so).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from cdcr_ctl.control.trajectory import Trajectory
from cdcr_ctl.errors import RigError

#: Legs of the sweep, in the order they are run for each (segment, β).
LEGS = ("start", "approach", "up", "down", "return")


@dataclass(frozen=True)
class SweepSpec:
    """Parameters of the calibration sweep (defaults: the paper's angles, our timing).

    ``segments``: 0-based segments to sweep, in order (None: all). ``betas_deg``: bending-plane
    directions. θ from ``theta_start_deg`` to ``theta_stop_deg`` in ``theta_step_deg`` steps.
    ``approach_step_deg``: dwell spacing on the slow ramps from/to straight (0: no dwells there).
    Rates are the bend rates dθ/dt (rad/s) of the moves; ``dwell_s`` the hold at each angle,
    ``start_dwell_s`` the hold at straight before the first ramp.
    """

    betas_deg: tuple[float, ...] = (0.0, 120.0, 240.0)
    theta_start_deg: float = 40.0
    theta_stop_deg: float = 90.0
    theta_step_deg: float = 5.0
    approach_step_deg: float = 10.0
    dwell_s: float = 1.0
    start_dwell_s: float = 1.0
    step_rate_rad_s: float = math.pi / 20.0
    approach_rate_rad_s: float = math.pi / 40.0
    segments: tuple[int, ...] | None = None

    def check(self) -> None:
        """Raise :class:`RigError` naming the field for an unusable spec."""
        if not self.betas_deg:
            raise RigError("sweep betas_deg: give at least one bending direction")
        for name in ("theta_step_deg", "dwell_s", "step_rate_rad_s", "approach_rate_rad_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise RigError(f"sweep {name}: must be > 0, got {v!r}")
        if not 0 < self.theta_start_deg <= self.theta_stop_deg:
            raise RigError(
                "sweep theta_start_deg/theta_stop_deg: need 0 < start <= stop, got "
                f"{self.theta_start_deg!r}, {self.theta_stop_deg!r}"
            )
        if self.approach_step_deg < 0 or self.start_dwell_s < 0:
            raise RigError("sweep approach_step_deg and start_dwell_s must be >= 0")

    def up_angles_deg(self) -> list[float]:
        """θ_start, θ_start + step, ..., θ_stop (θ_stop always included)."""
        n = math.floor((self.theta_stop_deg - self.theta_start_deg) / self.theta_step_deg + 1e-9)
        out = [self.theta_start_deg + j * self.theta_step_deg for j in range(n + 1)]
        if self.theta_stop_deg - out[-1] > 1e-9:
            out.append(self.theta_stop_deg)
        return out

    def approach_angles_deg(self) -> list[float]:
        """Dwell angles strictly between straight and θ_start on the ramps (ascending)."""
        if self.approach_step_deg <= 0:
            return []
        n = math.ceil(self.theta_start_deg / self.approach_step_deg - 1e-9)
        return [j * self.approach_step_deg for j in range(1, n)]


@dataclass(frozen=True)
class DwellSpec:
    """One planned dwell: times (s, trajectory clock), swept segment (0-based), β and θ (rad)."""

    t_start_s: float
    t_end_s: float
    segment: int
    beta_rad: float
    theta_rad: float
    leg: str


@dataclass(frozen=True)
class CalibrationSweep:
    """The sweep as a :class:`~cdcr_ctl.control.trajectory.Trajectory` plus its dwell plan."""

    trajectory: Trajectory
    dwells: tuple[DwellSpec, ...]
    spec: SweepSpec = field(default_factory=SweepSpec)

    @property
    def duration_s(self) -> float:
        return self.trajectory.duration_s

    def rows(self) -> list[list[float]]:
        """``[[t_s, seg1_theta, seg1_phi, ...], ...]`` (s, rad): the control socket's format."""
        return self.trajectory.rows()


def calibration_sweep(
    n_segments: int,
    spec: SweepSpec | None = None,
    bend_limit_rad: float | Sequence[float] | None = None,
) -> CalibrationSweep:
    """Build the sweep for a rig of ``n_segments`` segments (see the module docstring).

    ``bend_limit_rad`` (the config's ``limits.bend_rad``) is checked by the trajectory's own
    validation, as is the bend rate against the faster of the two move rates. Raises
    :class:`RigError` for a bad spec or segment index, :class:`~cdcr_ctl.errors.ConfigError`
    when a sample breaks the limits.
    """
    sp = SweepSpec() if spec is None else spec
    sp.check()
    if n_segments < 1:
        raise RigError(f"sweep: n_segments must be >= 1, got {n_segments}")
    segs = tuple(range(n_segments)) if sp.segments is None else tuple(sp.segments)
    for i in segs:
        if not 0 <= i < n_segments:
            raise RigError(f"sweep segments: {i} is not a segment index 0..{n_segments - 1}")
    up = [math.radians(v) for v in sp.up_angles_deg()]
    appr = [math.radians(v) for v in sp.approach_angles_deg()]

    t_list: list[float] = []
    psi_list: list[np.ndarray] = []
    dwells: list[DwellSpec] = []
    state = {"t": 0.0, "theta": 0.0}

    def sample(seg: int, beta: float, theta: float) -> None:
        psi = np.zeros((n_segments, 2))
        psi[seg] = (theta, beta)
        t_list.append(state["t"])
        psi_list.append(psi)

    def dwell(seg: int, beta: float, theta: float, hold_s: float, leg: str) -> None:
        t0 = state["t"]
        if not t_list or t_list[-1] != t0:
            sample(seg, beta, theta)
        state["t"] = t0 + hold_s
        sample(seg, beta, theta)
        dwells.append(DwellSpec(t0, state["t"], seg, beta, theta, leg))

    def move(seg: int, beta: float, theta: float, rate: float) -> None:
        state["t"] += abs(theta - state["theta"]) / rate
        state["theta"] = theta

    first = True
    for seg in segs:
        for beta_deg in sp.betas_deg:
            beta = math.radians(beta_deg)
            if first and sp.start_dwell_s > 0:
                dwell(seg, beta, 0.0, sp.start_dwell_s, "start")
            elif first:
                sample(seg, beta, 0.0)
            first = False
            for th in appr:
                move(seg, beta, th, sp.approach_rate_rad_s)
                dwell(seg, beta, th, sp.dwell_s, "approach")
            move(seg, beta, up[0], sp.approach_rate_rad_s)
            dwell(seg, beta, up[0], sp.dwell_s, "up")
            for th in up[1:]:
                move(seg, beta, th, sp.step_rate_rad_s)
                dwell(seg, beta, th, sp.dwell_s, "up")
            for th in reversed(up[:-1]):
                move(seg, beta, th, sp.step_rate_rad_s)
                dwell(seg, beta, th, sp.dwell_s, "down")
            for th in reversed(appr):
                move(seg, beta, th, sp.approach_rate_rad_s)
                dwell(seg, beta, th, sp.dwell_s, "return")
            move(seg, beta, 0.0, sp.approach_rate_rad_s)
            dwell(seg, beta, 0.0, sp.dwell_s, "return")

    traj = Trajectory(
        np.array(t_list), np.array(psi_list), "calibration_sweep", "<calibration sweep>"
    )
    rate = max(sp.step_rate_rad_s, sp.approach_rate_rad_s)
    traj.validate(n_segments, bend_limit_rad, rate)
    return CalibrationSweep(traj, tuple(dwells), sp)
