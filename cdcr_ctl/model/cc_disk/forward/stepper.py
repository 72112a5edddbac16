"""The stateful forward model of the simulator: :class:`ForwardStepper` and :func:`replay`.

Carries the friction state (stick memory of the disk-hole capstan friction, Qi et al. 2023
eq. 16-24, see :mod:`~cdcr_ctl.model.shared.friction`), the cable modes and the last solution from
call to call (warm start), applies the transmission effects (actuator -> cable) before the
robot, and falls back to sub-steps along the straight path when a step cannot be solved at
once. The solve itself is :class:`~cdcr_ctl.model.cc_disk.forward.solver.ForwardModel` (eq. 9-15,
33-37).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.forward.solver import SUBSTEP_LEVELS, ForwardModel, ForwardResult
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams
from cdcr_ctl.model.shared.friction import FrictionState


class ForwardStepper:
    """Stateful forward model for a simulator: ``step(q_act) -> ForwardResult``.

    Carries the friction state (stick memory), the cable modes and the last pose and tensions
    (warm start) from call to call, and applies the actuator effects of ``effects.actuator``
    (actuator -> cable, in order) before the robot.
    """

    def __init__(
        self,
        params: RobotParams,
        effects: Effects | None = None,
        state: FrictionState | None = None,
        tol: float | None = None,
    ) -> None:
        """``tol``: the Newton tolerance of :class:`ForwardModel` (largest scaled residual,
        rad-equivalent; its default when None)."""
        self.model = (
            ForwardModel(params, effects) if tol is None else ForwardModel(params, effects, tol=tol)
        )
        self.reset(state)

    def reset(self, state: FrictionState | None = None) -> None:
        """Back to the straight pretensioned pose (or ``state``) with fresh effect memories."""
        K = self.model.K
        self.state = FrictionState.initial(K) if state is None else state
        self.effect_states = [e.new_state(K) for e in self.model.effects.actuator]
        # the last solution, plain float lists (the predictor's arithmetic on K- and 2S-long
        # vectors is cheaper on floats than through numpy)
        self._x: list[float] | None = None
        self._T: list[float] | None = None
        self._modes: tuple[str, ...] | None = None
        self._q: list[float] | None = None  # last solved cable displacement (mm)
        self.last: ForwardResult | None = None
        # the solve before the last: (q, x, T) when both had the same modes (predictor)
        self._prev: tuple[list[float], list[float], list[float]] | None = None

    def cable_displacement(self, q_act_mm: np.ndarray) -> np.ndarray:
        """Actuator position -> cable pulled in at the spool, through the actuator effects."""
        q = np.asarray(q_act_mm, dtype=float)
        for e, st in zip(self.model.effects.actuator, self.effect_states, strict=True):
            q = e.to_cable(q, st)
        return q

    def step(self, q_act_mm: np.ndarray) -> ForwardResult:
        """Solve the pose for actuator positions ``q_act_mm`` (K,), mm; updates the memory.

        Warm-started from the last solution and its cable modes; if that fails, retried with
        every cable starting in stick, then from the straight pose, then along the straight path
        from the last solved cable displacement in 2, 4, ... ``2**SUBSTEP_LEVELS`` equal
        sub-steps (a quasi-static path between two keypoints: the friction memory follows it),
        and last from the straight pose with no friction memory. Raises :class:`ModelError` if
        every attempt fails (no static solution found); the memory then stays at the last
        solved pose.
        """
        q = self.cable_displacement(q_act_mm).tolist()
        res = self._solve_from_memory(q)
        if res is None:
            res = self._substep(q)
        self._accept(res, q)
        return res

    def _predict(self, q: list[float]) -> tuple[list[float], list[float], list[float]] | None:
        """Warm start extrapolated along the path (performance only): the last two solutions'
        bending vectors and anchor tensions continued linearly by the projection a of this
        step's cable displacement on the last one's (a path sampled at a steady rate, as a
        simulator's or a replay's, moves on a nearly straight line), and the cable displacement
        that guess solves (q_last + a (q_last - q_before)): the rest of the step, off that line
        (the drives' count quantisation, ~1 count in 7 on the Qi bend), the solver covers with
        one chord step before its first evaluation (``q_guess`` of :meth:`ForwardModel.solve`).
        None without two solutions of the same modes. The solve still converges to the
        solver's tolerance from here."""
        if self._prev is None or self._q is None or self._x is None or self._T is None:
            return None
        q1, x1, T1 = self._prev
        den = num = 0.0
        for qn, qa, qb in zip(q, self._q, q1, strict=True):
            d = qa - qb
            den += d * d
            num += (qn - qa) * d
        if den <= 0.0:
            return None
        a = num / den
        return (
            [v + a * (v - v1) for v, v1 in zip(self._x, x1, strict=True)],
            [v + a * (v - v1) for v, v1 in zip(self._T, T1, strict=True)],
            [v + a * (v - v1) for v, v1 in zip(self._q, q1, strict=True)],
        )

    def _solve_from_memory(self, q: list[float]) -> ForwardResult | None:
        guess = self._predict(q)
        if guess is not None:
            try:
                return self.model.solve(q, self.state, guess[0], guess[1], self._modes, guess[2])
            except ModelError:
                pass
        try:
            return self.model.solve(q, self.state, self._x, self._T, self._modes)
        except ModelError:
            pass
        try:
            return self.model.solve(q, self.state, self._x, self._T, None)
        except ModelError:
            pass
        try:  # the last pose can be a poor start after a large step: start straight
            return self.model.solve(q, self.state, None, None, None)
        except ModelError:
            return None

    def _accept(self, res: ForwardResult, q: list[float]) -> None:
        self._prev = None
        mem = (self._q, self._x, self._T)
        if self._modes == res.modes and all(v is not None for v in mem):
            self._prev = mem  # type: ignore[assignment]
        self.state = res.state
        self._x = res.x.tolist()
        self._T = res.tension_distal_N.tolist()
        self._modes = res.modes
        self._q = q
        self.last = res

    def _substep(self, q_list: list[float]) -> ForwardResult:
        start = (self.state, self._x, self._T, self._modes, self._q, self.last, self._prev)
        q = np.asarray(q_list, dtype=float)
        q0 = np.zeros_like(q) if self._q is None else np.asarray(self._q, dtype=float)
        err = "no attempt"
        for level in range(1, SUBSTEP_LEVELS + 1):
            n = 2**level
            ok = True
            for i in range(1, n + 1):
                qi = (q0 + (q - q0) * (i / n)).tolist()
                res = self._solve_from_memory(qi)
                if res is None:
                    ok = False
                    err = f"sub-step {i}/{n} failed"
                    break
                self._accept(res, qi)
            if ok:
                return res
            self.state, self._x, self._T, self._modes, self._q, self.last, self._prev = start
        try:  # last resort: a static pose without the friction memory of the path
            return self.model.solve(q, None, None, None, None)
        except ModelError:
            pass
        raise ModelError(
            f"forward model: no static solution for cable displacements "
            f"{np.round(q, 3).tolist()} mm ({err} with {2**SUBSTEP_LEVELS} sub-steps)"
        )


@dataclass(frozen=True)
class Replay:
    """A logged actuator path solved row by row (:func:`replay`).

    ``tip_mm`` (N, 3) base frame, NaN on a failed row; ``x`` (N, 2S) bending vectors (rad);
    ``tension_base_N``/``tension_actuator_N`` (N, K); ``failed``: (row, reason) of every row with
    no static solution (the replay went on from the last solved pose).
    """

    tip_mm: np.ndarray
    x: np.ndarray
    tension_base_N: np.ndarray
    tension_actuator_N: np.ndarray
    failed: list[tuple[int, str]]


def replay(stepper: ForwardStepper, q_act_mm: np.ndarray) -> Replay:
    """Solve every row of ``q_act_mm`` (N, K), mm, in order with ``stepper`` (memory kept).

    A row whose solve fails is named in :attr:`Replay.failed` with the reason and left NaN;
    the next row starts from the last solved pose and friction state.
    """
    q = np.asarray(q_act_mm, dtype=float)
    N, K, S2 = q.shape[0], stepper.model.K, 2 * stepper.model.S
    tip = np.full((N, 3), np.nan)
    x = np.full((N, S2), np.nan)
    tb = np.full((N, K), np.nan)
    ta = np.full((N, K), np.nan)
    failed: list[tuple[int, str]] = []
    for i in range(N):
        try:
            r = stepper.step(q[i])
        except ModelError as exc:
            failed.append((i, str(exc)))
            continue
        tip[i], x[i], tb[i], ta[i] = r.tip_mm, r.x, r.tension_base_N, r.tension_actuator_N
    return Replay(tip, x, tb, ta, failed)
