"""Forward solver, performance paths that must not change a bit: the solved chain taken from the
last Newton evaluation (ForwardModel._result with ``raw``) against the chain evaluated again, and
the kept last residual evaluation against a fresh one, along a stepped path with friction (stick,
slide, reversal) on the Qi rig and a three-segment rig."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from cc_robots import qi_params, three_params

from cdcr_ctl.model.cc_disk.forward import ForwardStepper
from cdcr_ctl.model.cc_disk.forward.solver import ForwardModel
from cdcr_ctl.model.cc_disk.params import Effects


def _path(K: int, n: int) -> np.ndarray:
    """Cable displacements (mm): a pull on cable 0 against the others, then back past zero."""
    s = np.concatenate((np.linspace(0.0, 1.0, n), np.linspace(1.0, -0.3, n)))
    d = np.zeros((2 * n, K))
    d[:, 0] = 2.0 * s
    d[:, 1:] = -2.0 * s[:, None] / (K - 1)
    return d


def _same(a, b) -> None:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.tobytes() == y.tobytes(), f.name
        else:
            assert x == y, f.name


@pytest.mark.parametrize("make", [qi_params, three_params])
def test_result_from_the_last_evaluation_equals_the_chain_evaluated_again(make, monkeypatch):
    p = make()
    stepper = ForwardStepper(p, Effects())
    taken: list[int] = [0]
    orig = ForwardModel._result

    def both(self, z, modes, it, res, w_prev, raw=None):
        fresh = orig(self, list(z), list(modes), it, res, list(w_prev), None)
        out = orig(self, z, modes, it, res, w_prev, raw)
        _same(out, fresh)  # exact: the same calls on the same floats
        taken[0] += raw is not None
        return out

    monkeypatch.setattr(ForwardModel, "_result", both)
    for q in _path(p.n_cables, 40):
        stepper.step(q)
    assert taken[0] >= 70  # the reuse path ran (80 solves)


def test_kept_evaluation_equals_a_fresh_one():
    m = ForwardModel(qi_params(), Effects())
    S2, K = 2 * m.S, m.K
    z = [0.1, -0.05][:S2] + [2.0] * K + [0.3] * K
    first = m._raw(z)
    assert m._raw(list(z)) is first  # kept for the same z
    again = m._raw_eval(list(z))
    assert repr(again) == repr(first)
    m.ft = type(m.ft)(m.params, m.effects)  # a new force transfer: evaluated anew
    assert m._raw(z) is not first
