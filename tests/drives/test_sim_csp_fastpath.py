"""The simulated EPOS's CSP sub-steps written out on local variables (the lock-step rig's case:
constant load torque, no hard stops) against the general path (a load function, here returning
that same constant): the same operations in the same order, so every state variable must come
out bit for bit the same, through current saturation, and through a following-error fault."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import Mode, State
from cdcr_ctl.sim.lockstep.rig import LockstepRig
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


@pytest.mark.timeout(120)
def test_inline_csp_substeps_equal_the_general_path_bit_for_bit(monkeypatch):
    loaded = load_sim_config(ROOT / "config" / "sim" / "qi2023-truth-clean.yaml")
    ctl = load_rig_config(loaded.rig_path)
    saturated = [0]
    copysign = math.copysign

    def counting_copysign(a: float, b: float) -> float:
        saturated[0] += 1  # Motor.substep and the inline path clamp the current with it only
        return copysign(a, b)

    with LockstepRig.open(loaded, ctl, str(loaded.rig_path), truth_process=False) as rig:
        rig.drives.enable()
        n = rig.nodes[0]
        assert n.state is State.OPERATION_ENABLED and n.mode == Mode.CYCLIC_SYNC_POSITION
        assert n.motor.p.hard_stops_counts is None  # the fast path's case
        n.advance_on_sync = False  # only this test steps the node
        window = n._value(epos.FOLLOWING_ERROR_WINDOW)
        start = _state(n)
        monkeypatch.setattr(math, "copysign", counting_copysign)
        fast = _run(n, start, SATURATING, use_load_fn=False)
        monkeypatch.setattr(math, "copysign", copysign)
        general = _run(n, start, SATURATING, use_load_fn=True)
        fast_fault = _run(n, start, FAULTING, use_load_fn=False)
        general_fault = _run(n, start, FAULTING, use_load_fn=True)
        _restore(n, start)
        n.load_fn = None
    # floats compared exactly: the subject is the same arithmetic in the same order
    assert fast == general
    assert fast_fault == general_fault
    assert saturated[0] > 0  # the 6000-count jump hit the current limit
    assert all(s[13] is State.OPERATION_ENABLED for s in fast)
    assert max(s[10] for s in fast) < window
    assert fast_fault[-1][13] is State.FAULT and max(s[10] for s in fast_fault) > window
