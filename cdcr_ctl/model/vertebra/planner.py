"""Joystick end-following of the vertebra arm (fuel-tank vertebra robot paper, section 2.2, eq. 5
and 9).

:class:`EndFollowPlanner`: a pure state machine (no clocks, no I/O) that steers the distal joint
and lets the proximal ones follow, step by step; each step's cable changes (eq. 5) become
synchronised pulses and pulse rates of the linear modules (eq. 9, :func:`synchronise`).

Units: rad, mm, pulses, Hz.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.vertebra.attitude import _wrap
from cdcr_ctl.model.vertebra.cables import cable_displacements, psi_from_xs, x_from_psi
from cdcr_ctl.model.vertebra.forward import _psi_array
from cdcr_ctl.model.vertebra.params import FOLLOW_STEP_RAD, VertebraArm


# =========================================================================== end following
@dataclass(frozen=True)
class SyncStep:
    """One synchronised move of every linear module (section 2.2, eq. 9).

    ``psi_from``/``psi_to`` (N, 2) joint poses; ``delta_mm`` (C,) exact cable displacement change
    (eq. 5); ``pulses`` (C,) signed integer pulses m sent (eq. 9, rounded on the absolute
    position so rounding never accumulates); ``pulse_rate_hz`` (C,) f >= 0 (eq. 9);
    ``velocity_mm_s`` (C,) = f c / s; ``duration_s``: the same for every axis, set by the axis
    that needs longest at its own speed limit.
    """

    psi_from: np.ndarray
    psi_to: np.ndarray
    delta_mm: np.ndarray
    pulses: np.ndarray
    pulse_rate_hz: np.ndarray
    velocity_mm_s: np.ndarray
    duration_s: float


def synchronise(pulses: np.ndarray, arm: VertebraArm) -> tuple[float, np.ndarray]:
    """(duration_s, pulse_rate_hz per axis) so every axis ends together (section 2.2).

    duration = max_k |m_k| / f_max,k (the longest move at its speed limit), f_k = |m_k| / duration
    <= f_max,k for every axis. All zero: (0, zeros).
    """
    m = np.abs(np.asarray(pulses, dtype=float))
    duration = float(np.max(m / arm.max_pulse_rate_hz)) if m.size else 0.0
    if duration <= 0.0:
        return 0.0, np.zeros_like(m)
    return duration, m / duration


class FollowMode(enum.Enum):
    """IDLE: at the targets; STEER: the distal joint moves towards the joystick target;
    FOLLOW: the joints move to the poses shifted down by :meth:`EndFollowPlanner.advance`."""

    IDLE = "idle"
    STEER = "steer"
    FOLLOW = "follow"


@dataclass(frozen=True)
class FollowParams:
    """Joystick end-following parameters (section 2.2).

    ``step_rad``: the largest change of any joint's bending vector per synchronised step (the
    paper's 0.05 rad). ``theta_increment_rad``/``phi_increment_rad``: change of the distal target
    per :meth:`EndFollowPlanner.steer` call at full stick deflection. ``theta_max_rad``: bend limit.
    """

    step_rad: float = FOLLOW_STEP_RAD
    theta_increment_rad: float = 0.02
    phi_increment_rad: float = 0.05
    theta_max_rad: float = math.pi / 2

    def __post_init__(self) -> None:
        if not (
            self.step_rad > 0
            and self.theta_increment_rad >= 0
            and self.phi_increment_rad >= 0
            and 0 < self.theta_max_rad <= math.pi
        ):
            raise ModelError("follow parameters: step > 0, increments >= 0, 0 < theta_max <= pi")


@dataclass
class EndFollowPlanner:
    """Joystick end-following (section 2.2) as a pure state machine: no clocks, no I/O.

    Only the distal joint is steered (:meth:`steer`: increments of its (theta, phi) from the
    normalised stick axes). "Follow" (:meth:`advance`, the paper's forward button, Fig. 12): every
    proximal joint takes the pose its distal neighbour has now, target_i = psi_{i+1} for
    i < N-1, the distal joint keeps its pose, so the shape the tip has been steered into moves
    one joint towards the base, as when a snake advances. Moves are cut into synchronised steps
    (:meth:`next_step`): K = ceil(max_i |x_target,i - x_i| / step_rad) steps in which every joint's
    bending vector moves by 1/K of its remaining way (straight lines in x, all joints arriving
    together, none moving more than ``step_rad`` per step); each step's cable changes (eq. 5) are
    sent as pulses (eq. 9) with the rates of :func:`synchronise`. The caller runs a step for its
    ``duration_s`` and then asks for the next; while FOLLOW runs, the stick is ignored.
    """

    arm: VertebraArm
    params: FollowParams = field(default_factory=FollowParams)
    psi: np.ndarray | None = None
    target: np.ndarray = field(init=False)
    position_pulses: np.ndarray = field(init=False)
    mode: FollowMode = field(init=False, default=FollowMode.IDLE)

    def __post_init__(self) -> None:
        N = self.arm.n_joints
        self.psi = np.zeros((N, 2)) if self.psi is None else _psi_array(self.psi, N).copy()
        if np.any(self.psi[:, 0] < 0) or np.any(self.psi[:, 0] > self.params.theta_max_rad):
            raise ModelError("initial bends must be in [0, theta_max]")
        self.target = self.psi.copy()
        self.position_pulses = np.rint(
            cable_displacements(self.arm, self.psi) * self.arm.pulses_per_mm
        ).astype(np.int64)

    def steer(self, axis_x: float, axis_y: float) -> bool:
        """Move the distal target: theta += axis_y * theta_increment (clamped to [0, theta_max]),
        phi += axis_x * phi_increment; axes in [-1, 1] (clipped). Returns False (ignored) while a
        follow move runs."""
        if self.mode is FollowMode.FOLLOW:
            return False
        jx = float(np.clip(axis_x, -1.0, 1.0))
        jy = float(np.clip(axis_y, -1.0, 1.0))
        t = self.target[-1]
        theta = float(
            np.clip(t[0] + jy * self.params.theta_increment_rad, 0.0, self.params.theta_max_rad)
        )
        phi = _wrap(float(t[1]) + jx * self.params.phi_increment_rad)
        self.target[-1] = (theta, phi)
        self.mode = FollowMode.STEER
        return True

    def set_distal_target(self, theta: float, phi: float) -> bool:
        """Set the distal target directly (clamped); False while a follow move runs."""
        if self.mode is FollowMode.FOLLOW:
            return False
        self.target[-1] = (float(np.clip(theta, 0.0, self.params.theta_max_rad)), _wrap(phi))
        self.mode = FollowMode.STEER
        return True

    def set_targets(self, psi: np.ndarray) -> bool:
        """Move every joint to ``psi`` (N, 2) (bends clamped to [0, theta_max]), e.g. back to
        straight; False (ignored) while a follow move runs."""
        if self.mode is FollowMode.FOLLOW:
            return False
        p = _psi_array(psi, self.arm.n_joints).copy()
        p[:, 0] = np.clip(p[:, 0], 0.0, self.params.theta_max_rad)
        self.target = p
        self.mode = FollowMode.STEER
        return True

    def advance(self) -> bool:
        """Start a follow move: target_i = psi_{i+1} (current poses) for the proximal joints, the
        distal joint's target = its current pose. False if a follow move is already running."""
        if self.mode is FollowMode.FOLLOW:
            return False
        assert self.psi is not None
        self.target[:-1] = self.psi[1:]
        self.target[-1] = self.psi[-1]
        self.mode = FollowMode.FOLLOW
        return True

    def next_step(self) -> SyncStep | None:
        """The next synchronised step towards the targets, or None (mode -> IDLE) when there."""
        assert self.psi is not None
        x = x_from_psi(self.psi)
        xt = x_from_psi(self.target)
        rem = xt - x
        dist = float(np.max(np.hypot(rem[:, 0], rem[:, 1])))
        if dist <= 1e-12:
            self.psi = self.target.copy()
            self.mode = FollowMode.IDLE
            return None
        K = max(1, math.ceil(dist / self.params.step_rad - 1e-9))
        x_new = xt if K == 1 else x + rem / K
        psi_new = psi_from_xs(x_new, self.target[:, 1])
        if K == 1:
            psi_new = self.target.copy()
        q_old = cable_displacements(self.arm, self.psi)
        q_new = cable_displacements(self.arm, psi_new)
        pos_new = np.rint(q_new * self.arm.pulses_per_mm).astype(np.int64)
        pulses = pos_new - self.position_pulses
        duration, rate = synchronise(pulses, self.arm)
        step = SyncStep(
            psi_from=self.psi.copy(),
            psi_to=psi_new.copy(),
            delta_mm=q_new - q_old,
            pulses=pulses,
            pulse_rate_hz=rate,
            velocity_mm_s=rate / self.arm.pulses_per_mm,
            duration_s=duration,
        )
        self.psi = psi_new
        self.position_pulses = pos_new
        return step

    def run(self, max_steps: int = 10_000) -> list[SyncStep]:
        """All remaining steps (for tests and offline planning)."""
        steps: list[SyncStep] = []
        for _ in range(max_steps):
            s = self.next_step()
            if s is None:
                return steps
            steps.append(s)
        raise ModelError(f"end-following did not finish in {max_steps} steps")
