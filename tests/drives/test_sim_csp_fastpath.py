"""The simulated EPOS's CSP sub-steps written out on local variables (the lock-step rig's case:
constant load torque, no hard stops) against the general path (a load function, here returning
that same constant): the same operations in the same order, so every state variable agrees to
rounding, through current saturation, and through a following-error fault."""

from __future__ import annotations

import math
from pathlib import Path

import canopen
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import Mode, State
from cdcr_ctl.sim.epos.node import SimEpos
from cdcr_ctl.sim.epos.plant import MotorParams
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[2]
TORQUE_NM = -0.15  # at the gearbox output: ~0.75 A of holding current

#: CSP targets (counts from the start) per 4 ms step: small moves, a 6000-count jump the current
#: limit cuts (saturation: the integral frozen) but within the 20000-count following-error
#: window, the way back, holds.
SATURATING = [0, 40, 120, 260, 260, 6000, 6000, 6000, 6000, 1000, 1000, 0, 0, -300, -300]
#: A jump far past the window: the drive faults (EMCY 0x8611) on its first sub-steps.
FAULTING = [0, 40, 60_000, 60_000, 0]


def _state(n) -> tuple:
    m, p = n.motor, n.profile
    return (
        m.x, m.v, m.i, m._integral, p.x, p.v, p.a, n._csp_t, n._csp_from, n._csp_to,
        n.max_following_error_counts, n.following_error, n._ferr_s, n.state,
    )  # fmt: skip


def _restore(n, s: tuple) -> None:
    m, p = n.motor, n.profile
    (m.x, m.v, m.i, m._integral, p.x, p.v, p.a, n._csp_t, n._csp_from, n._csp_to,
     n.max_following_error_counts, n.following_error, n._ferr_s, n.state) = s  # fmt: skip


def _run(n, start: tuple, targets: list[int], use_load_fn: bool) -> list[tuple]:
    _restore(n, start)
    n.load_torque_Nm = TORQUE_NM
    n.load_fn = (lambda x, v: TORQUE_NM) if use_load_fn else None
    out = []
    for target in targets:
        n._csp_from, n._csp_to, n._csp_t = n.profile.x, start[0] + target, 0.0
        n.step(0.004)
        out.append(_state(n))
    return out


def _close(a: tuple, b: tuple, scale: tuple) -> bool:
    """The floats of two states within a few ulp of their scale; the rest (enums) equal."""
    return all(
        math.isclose(x, y, rel_tol=REL_TOL, abs_tol=REL_TOL * s) if s else x == y
        for x, y, s in zip(a, b, scale, strict=True)
    )


#: Both paths do the same operations in the same order, so they should agree to the last bit;
#: the test allows each float 1e-12 of its run's largest magnitude. The error bound: one rounding
#: (2**-53 relative) per operation, a few hundred operations per 4 ms step (the sub-steps), 15
#: steps: ~1e-12 at the most, were the order ever to differ.
REL_TOL = 1e-12


@pytest.mark.timeout(120)
def test_inline_csp_substeps_agree_with_the_general_path(monkeypatch):
    loaded = load_sim_config(ROOT / "config" / "sim" / "qi2023-truth-clean.yaml")
    ctl = load_rig_config(loaded.rig_path)
    saturated = [0]
    copysign = math.copysign

    def counting_copysign(a: float, b: float) -> float:
        saturated[0] += 1  # Motor.substep and the inline path clamp the current with it only
        return copysign(a, b)

    # The node alone on a network of its own, stepped only by this test (no bus, no threads of
    # a rig acting on it), configured like the rig's first drive.
    d = ctl.drives[0]
    n = SimEpos(canopen.Network(), 1, d.type, MotorParams(counts_per_rev=d.encoder_counts_per_rev))
    for w in epos.configuration_writes(d, ctl.can):
        if w.index == epos.HEARTBEAT_PRODUCER:
            continue  # a heartbeat needs a bus; this node has none
        n.node.set_data(w.index, w.sub, w.data, check_writable=True)
    n.advance_on_sync = False
    n.force_state(State.OPERATION_ENABLED, mode=Mode.CYCLIC_SYNC_POSITION)
    assert n.motor.p.hard_stops_counts is None  # the fast path's case
    window = n._value(epos.FOLLOWING_ERROR_WINDOW)
    start = _state(n)
    monkeypatch.setattr(math, "copysign", counting_copysign)
    fast = _run(n, start, SATURATING, use_load_fn=False)
    monkeypatch.setattr(math, "copysign", copysign)
    general = _run(n, start, SATURATING, use_load_fn=True)
    fast_fault = _run(n, start, FAULTING, use_load_fn=False)
    general_fault = _run(n, start, FAULTING, use_load_fn=True)
    for a_run, b_run in ((fast, general), (fast_fault, general_fault)):
        scale = tuple(
            max(abs(s[k]) for s in a_run) or 1.0 if isinstance(a_run[0][k], float) else 0.0
            for k in range(len(a_run[0]))
        )
        for k, (a, b) in enumerate(zip(a_run, b_run, strict=True)):
            assert _close(a, b, scale), (k, a, b)
    assert saturated[0] > 0  # the 6000-count jump hit the current limit
    assert all(s[13] is State.OPERATION_ENABLED for s in fast)
    assert max(s[10] for s in fast) < window
    assert fast_fault[-1][13] is State.FAULT and max(s[10] for s in fast_fault) > window
