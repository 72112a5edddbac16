"""Joystick end-following (fuel-tank vertebra paper, section 2.2) as the control loop's setpoint.

:class:`EndFollowSource` is a ``SetpointSource`` (:mod:`cdcr_ctl.control.ports`): the loop samples
it every cycle at its own time and gets the joints' (theta, phi) (N, 2, rad). It drives the pure
planner :class:`~cdcr_ctl.model.vertebra.EndFollowPlanner` from the joystick state, which reaches
it through an injected callable (no I/O here, no clock: time is the loop's ``t_s``):

- at every ``steer_period_s`` tick the stick moves the DISTAL target
  (:meth:`EndFollowPlanner.steer`: y -> theta, x -> phi, full deflection = one increment per tick);
- a press (rising edge) of ``advance_button`` starts a follow move
  (:meth:`EndFollowPlanner.advance`: the proximal joints take their distal neighbour's pose); the
  stick is ignored until it ends;
- the planner cuts every move into synchronised steps of at most ``step_rad`` (0.05 rad) of any
  joint; each step runs for the planner's ``duration_s``, set by the axis with the longest move at
  its own speed limit (eq. 9; times ``speed_fraction``), and inside a step every cable moves
  LINEARLY in time from its start
  to its end (as the paper's steppers do at constant pulse rates): the setpoint at fraction s of
  the step is the forward kinematics (inverse of eq. 5) of q_from + s (q_to - q_from). So every
  axis starts and ends each step together and none exceeds its speed limit.

:attr:`EndFollowSource.log` records each step (start, duration, cable start/end) for the session
checks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from cdcr_ctl.model.vertebra import (
    EndFollowPlanner,
    FollowMode,
    SyncStep,
    cable_displacements,
    joints_from_displacements,
    psi_from_xs,
    x_from_psi,
)

#: Joystick state as the source reads it: (x, y, pressed button names), axes in [-1, 1].
JoystickRead = Callable[[], tuple[float, float, frozenset[str]]]
#: Default steer tick (s): the distal target moves by at most one increment per tick.
STEER_PERIOD_S = 0.1
#: Share of each axis' speed limit the planned steps use: the rest is for the compensation the
#: model adds on top (sag, attitude loop) and for the interpolation's round trip.
SPEED_FRACTION = 0.8


@dataclass(frozen=True)
class StepRecord:
    """One executed synchronised step: loop time it started (s), its duration (s), the cable
    displacements at its start and end (mm pulled in), the joint poses (rad), the planner mode."""

    t_start_s: float
    duration_s: float
    q_from_mm: np.ndarray
    q_to_mm: np.ndarray
    psi_from: np.ndarray
    psi_to: np.ndarray
    mode: str


@dataclass
class EndFollowSource:
    """SetpointSource of joystick end-following; ``duration_s`` is infinite (an operator session).

    ``joystick``: returns the current stick state; ``advance_button``: the "forward" button
    (Fig. 12); ``steer_period_s``: steer tick; ``speed_fraction``: each step lasts
    max_k |dq_k| / (speed_fraction v_max,k) (:data:`SPEED_FRACTION`; 1 is the paper's
    synchronisation at the limits). Sample times must not decrease.
    """

    planner: EndFollowPlanner
    joystick: JoystickRead
    advance_button: str = "BTN_SOUTH"
    steer_period_s: float = STEER_PERIOD_S
    speed_fraction: float = SPEED_FRACTION
    log: list[StepRecord] = field(default_factory=list)
    _step: SyncStep | None = field(default=None, init=False)
    _t_step: float = field(default=0.0, init=False)
    _q_from: np.ndarray | None = field(default=None, init=False)
    _q_to: np.ndarray | None = field(default=None, init=False)
    _x_prev: np.ndarray | None = field(default=None, init=False)
    _next_steer_s: float = field(default=-math.inf, init=False)
    _pressed: bool = field(default=False, init=False)
    _t_last: float = field(default=-math.inf, init=False)

    @property
    def duration_s(self) -> float:
        return math.inf

    @property
    def busy(self) -> bool:
        """True while a step runs or the planner has somewhere to go."""
        return self._step is not None or self.planner.mode is not FollowMode.IDLE

    def sample(self, t_s: float) -> np.ndarray:
        """Joint poses (N, 2) at loop time ``t_s`` (s)."""
        t = max(float(t_s), self._t_last)
        self._t_last = t
        if self._step is not None and t >= self._t_step + self._step.duration_s:
            self._finish_step()
        if self._step is None:
            self._read_stick(t)
            self._start_step(t)
        if self._step is None:
            assert self.planner.psi is not None
            return self.planner.psi.copy()
        return self._interpolate(t)

    # ---------------------------------------------------------------- internals
    def _read_stick(self, t: float) -> None:
        x, y, buttons = self.joystick()
        pressed = self.advance_button in buttons
        if pressed and not self._pressed:
            self.planner.advance()
        self._pressed = pressed
        steering = t >= self._next_steer_s and (x != 0.0 or y != 0.0)
        if steering and self.planner.steer(x, y):
            self._next_steer_s = t + self.steer_period_s

    def _start_step(self, t: float) -> None:
        assert self.planner.psi is not None
        psi_from = self.planner.psi.copy()
        mode = self.planner.mode.value
        step = self.planner.next_step()
        if step is None:
            return
        if step.duration_s <= 0.0:  # no cable moves (e.g. only phi of a straight joint)
            return
        arm = self.planner.arm
        v = np.array([m.v_max_mm_s for m in arm.modules]) * self.speed_fraction
        duration = float(np.max(np.abs(step.delta_mm) / v))
        self._step = replace(step, duration_s=duration)
        self._t_step = t
        self._q_from = cable_displacements(arm, psi_from)
        self._q_to = self._q_from + step.delta_mm
        self._x_prev = x_from_psi(psi_from)
        self.log.append(
            StepRecord(t, duration, self._q_from, self._q_to, psi_from, step.psi_to, mode)
        )

    def _finish_step(self) -> None:
        self._step = None

    def _interpolate(self, t: float) -> np.ndarray:
        step = self._step
        assert step is not None and self._q_from is not None and self._q_to is not None
        s = min(1.0, (t - self._t_step) / step.duration_s)
        if s >= 1.0:
            return step.psi_to.copy()
        q = self._q_from + s * (self._q_to - self._q_from)
        x = joints_from_displacements(self.planner.arm, q, self._x_prev)
        self._x_prev = x
        return psi_from_xs(x, step.psi_to[:, 1])


@dataclass(frozen=True)
class StickFrame:
    """A scripted joystick state from ``t_s`` on (s): axes in [-1, 1] and pressed buttons."""

    t_s: float
    x: float = 0.0
    y: float = 0.0
    buttons: frozenset[str] = frozenset()


def paper_session(advance_button: str = "BTN_SOUTH", scale: float = 1.0) -> list[StickFrame]:
    """The joystick session of the paper's Fig. 12, scripted for the default follow parameters
    (0.02 rad of bend and 0.05 rad of direction per 0.1 s tick at full deflection):

    1. steer the distal joint towards theta = 1.0 rad (57.3 deg; paper 57.32 deg) in the direction
       phi = 0.65 rad (37.2 deg; paper 37.83 deg): 1.3 s of (x, y) = (1, 1), 3.7 s of y = 1 (the
       stick is read between steps, so a few ticks fall out: the commanded pose is what the
       ticks that were read add up to, e.g. 0.96 rad);
    2. press "forward": the middle joint takes the distal pose (the paper's first following);
    3. steer the distal bend back by 0.4 rad (paper: to 34.39 deg): 2 s of y = -1;
    4. press "forward" again: every joint takes its distal neighbour's pose.

    ``scale`` (0, 1] shortens the bend moves (tests). Times leave room for the moves to finish
    (the source ignores the stick while a follow move runs).
    """
    n_xy, n_y, n_back = 13, max(0, round(37 * scale)), max(1, round(20 * scale))
    b = frozenset({advance_button})
    t1 = 0.1 * n_xy
    t2 = t1 + 0.1 * n_y
    t_fwd1 = t2 + 1.0
    t_back = t_fwd1 + 15.0 * max(scale, 0.2)
    t3 = t_back + 0.1 * n_back
    t_fwd2 = t3 + 1.0
    return [
        StickFrame(0.0, 1.0, 1.0),
        StickFrame(t1, 0.0, 1.0),
        StickFrame(t2),
        StickFrame(t_fwd1, buttons=b),
        StickFrame(t_fwd1 + 0.3),
        StickFrame(t_back, 0.0, -1.0),
        StickFrame(t3),
        StickFrame(t_fwd2, buttons=b),
        StickFrame(t_fwd2 + 0.3),
    ]


def scripted_stick(script: list[StickFrame], clock: Callable[[], float]) -> JoystickRead:
    """A :data:`JoystickRead` that plays ``script`` against ``clock`` (s)."""

    def read() -> tuple[float, float, frozenset[str]]:
        t = clock()
        cur = StickFrame(-math.inf)
        for f in script:
            if f.t_s <= t:
                cur = f
        return cur.x, cur.y, cur.buttons

    return read


def plan_session(
    planner: EndFollowPlanner,
    script: list[StickFrame],
    dt_s: float,
    advance_button: str = "BTN_SOUTH",
    max_s: float = 600.0,
    speed_fraction: float = SPEED_FRACTION,
) -> tuple[np.ndarray, np.ndarray, EndFollowSource]:
    """Run a scripted session offline: sample an :class:`EndFollowSource` (steps at
    ``speed_fraction`` of each axis' speed limit) every ``dt_s`` until the script is over and the
    planner is idle. Returns (t_s (M,), psi (M, N, 2), the source)."""
    now = [0.0]
    source = EndFollowSource(
        planner,
        scripted_stick(script, lambda: now[0]),
        advance_button,
        speed_fraction=speed_fraction,
    )
    t_script = max((f.t_s for f in script), default=0.0)
    ts, ps = [], []
    t = 0.0
    while t <= max_s:
        now[0] = t
        ps.append(source.sample(t))
        ts.append(t)
        if t > t_script and not source.busy:
            break
        t += dt_s
    return np.array(ts), np.array(ps), source
