"""Tip sensitivities of a forward replay to the robot's parameters, by implicit differentiation.

A replay (:func:`~cdcr_ctl.model.cc_disk.forward.stepper.replay`) solves, row after row, the
static equations E(z_i; g, w_i) = 0 of :class:`~cdcr_ctl.model.cc_disk.forward.solver.ForwardModel`
(Qi et al. 2023 eq. 9-15 moment balance, eq. 33-37 cable compatibility, eq. 16-24 friction with
stick memory) for z = [x (2S, rad), T (K, N), s (K)] at the row's cable displacements, with the
solved cable modes (stick, slide, slack, free) and the friction memory w_i (K, mm): the material
drawn out at the previous accepted solve, w_i = w(z_{i-1}; g). With the modes held, the solution
is a smooth function of the parameters g (EI, EA, pretension, friction, routing, masses ...) and

    dz_i/dg = -E_z^-1 ( E_g + E_w dw_i/dg ),     dw_{i+1}/dg = w_z dz_i/dg + w_g

(E_z the solver's own Jacobian at the solution, E_w = -1 on the rows of stuck cables and 0
elsewhere, scaled as the solver scales them). E_g and w_g are forward differences of the
solver's raw functions at the solved z with one parameter changed (one evaluation per parameter
and solve, against a whole replay per parameter for a forward-difference Jacobian of the
replay), and the tip's sensitivity is (d tip/dx) dx/dg (eq. 1-3, differences of the tip map).

Every accepted solve is followed, sub-steps included (:class:`SensitivityStepper` records
them). A row whose solve had no friction memory (the stepper's last resort) restarts the
memory's sensitivity at zero. The result is the derivative of the branch the replay is on: a
cable that would change mode within a forward-difference step shows as a jump in that
difference and not here. Actuator effects (play) are taken as they are (parameters that change
them, such as ``backlash_mm``, are not differentiated here), and rigid cables are not supported.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.forward.solver import (
    FREE,
    SLACK,
    STICK,
    ForwardModel,
    ForwardResult,
)
from cdcr_ctl.model.cc_disk.forward.stepper import ForwardStepper
from cdcr_ctl.model.cc_disk.kinematics import tip_frame_fast
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams

#: Step (rad) of the differences of the tip map in the bending vectors.
_H_TIP = 1e-7
#: Largest scaled residual (rad-equivalent) at which a recorded solve counts as solved with
#: the memory the stepper held (otherwise it was solved without memory: last resort).
_SOLVED = 1e-6


class SensitivityStepper(ForwardStepper):
    """A :class:`ForwardStepper` that records every accepted solve (cable displacement, the
    friction memory it started from, the solution) for :func:`replay_sensitivity`."""

    def __init__(self, params: RobotParams, effects: Effects | None = None) -> None:
        super().__init__(params, effects)
        self.solves: list[tuple[list[float], tuple[float, ...], ForwardResult]] = []

    def _accept(self, res: ForwardResult, q: list[float]) -> None:
        self.solves.append((list(q), tuple(self.state.w_mm), res))
        super()._accept(res, q)


def replay_sensitivity(
    params: RobotParams,
    effects: Effects | None,
    variants: Sequence[RobotParams],
    steps: Sequence[float],
    q_act_mm: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Replay ``q_act_mm`` (N, K) mm with ``params`` and the tip's derivative per parameter.

    ``variants[j]`` is ``params`` with parameter j changed by ``steps[j]`` (in whatever variable
    the caller differentiates: the difference quotient of the raw functions is divided by it).
    Returns (tip (N, 3) mm, NaN where a row has no solution; d tip / d g (N, 3, n) mm per unit
    of the caller's variable, 0 on rows with no solution). Raises :class:`ModelError` for rigid
    cables (no elastic equations to differentiate)."""
    eff = Effects() if effects is None else effects
    st = SensitivityStepper(params, eff)
    model = st.model
    if model.rigid:
        raise ModelError("replay sensitivities need elastic cables (EA finite)")
    others = [ForwardModel(p, eff) for p in variants]
    q = np.asarray(q_act_mm, dtype=float)
    N, n = len(q), len(variants)
    S2, K = 2 * model.S, model.K
    tip = np.full((N, 3), np.nan)
    dtip = np.zeros((N, 3, n))
    dw = np.zeros((K, n))  # d w_prev / d g of the memory the next solve starts from
    h = np.asarray(steps, dtype=float)
    done = 0
    for i in range(N):
        try:
            r = st.step(q[i])
        except ModelError:
            continue
        for q_c, w_prev, res in st.solves[done:]:
            dz, dw = _solve_sensitivity(model, others, h, q_c, w_prev, res, dw, S2, K)
        done = len(st.solves)
        tip[i] = r.tip_mm
        dtip[i] = _tip_jacobian(r.x.tolist(), model._lengths) @ dz[:S2]
    return tip, dtip


def _solve_sensitivity(model, others, h, q_c, w_prev, res, dw, S2, K):
    """(dz/dg (2S+2K, n), dw/dg (K, n)) of one accepted solve (module docstring)."""
    modes = list(res.modes)
    T = [0.0 if m == SLACK else float(v) for m, v in zip(modes, res.tension_distal_N, strict=True)]
    # s as solved: a free cable (out of slack, with friction) slides in the pull direction,
    # s = +1, whatever direction its state records after the solve
    s = [1.0 if m == FREE else float(v) for m, v in zip(modes, res.state.s, strict=True)]
    z = [float(v) for v in res.x] + T + s
    raw = model._raw(z)
    Jraw = model._jacobian(raw, z, modes)
    A = model._assemble(Jraw, modes)
    base = _flat(raw)
    stick = np.array([m == STICK for m in modes])
    # was this solve's memory the stepper's? (the last resort solves without any)
    w_now = np.array([c[2] for c in raw[4]])
    if stick.any() and np.max(np.abs(w_now - np.array(w_prev))[stick]) * model._w_len > _SOLVED:
        dw = np.zeros_like(dw)
    # d E / d g, scaled as the solver's residual (the rows E depends on g through)
    Eg = np.zeros((S2 + 2 * K, len(others)))
    Wg = np.zeros((K, len(others)))
    for j, other in enumerate(others):
        d = (_flat(other._raw_eval(z)) - base) / h[j]
        Eg[:S2, j] = d[:S2] * model._w_mom
        comp = np.array([m != SLACK for m in modes])
        Eg[S2 : S2 + K, j] = np.where(comp, d[S2 : S2 + K] * model._w_len, 0.0)
        Eg[S2 + K :, j] = np.where(stick, d[S2 + K :] * model._w_len, 0.0)
        Wg[:, j] = d[S2 + K :]
    Eg[S2 + K :] -= np.where(stick[:, None], dw * model._w_len, 0.0)
    try:
        dz = np.linalg.solve(A, -Eg)
    except np.linalg.LinAlgError:
        dz = np.linalg.lstsq(A, -Eg, rcond=None)[0]
    dw_next = Jraw[S2 + K :] @ dz + Wg
    return dz, dw_next


def _flat(raw) -> np.ndarray:
    """The solver's raw functions [moments (2S), q (K), w (K)] as one vector."""
    _, _, _, mom, cab = raw
    return np.concatenate((mom, [c[3] for c in cab], [c[2] for c in cab]))


def _tip_jacobian(xs: list[float], lengths: list[float]) -> np.ndarray:
    """d tip / d x (3, 2S) mm/rad of eq. 1-3 by forward differences of the tip map."""
    p0 = np.array(tip_frame_fast(xs, lengths)[1])
    out = np.empty((3, len(xs)))
    for j in range(len(xs)):
        xj = list(xs)
        xj[j] += _H_TIP
        out[:, j] = (np.array(tip_frame_fast(xj, lengths)[1]) - p0) / _H_TIP
    return out
