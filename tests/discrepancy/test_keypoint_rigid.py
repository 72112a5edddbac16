"""The registration candidate's rigidity test (:mod:`cdcr_ctl.discrepancy.keypoint_rigid`) and
the tie rule that uses it, on synthetic tips (no replay): a frame fixed in the lab passes, a
tilt that grows with the split variable (what a sag a frame stands in for does) does not, and
only a non-rigid registration hands a tie to its rival."""

from __future__ import annotations

import math

import numpy as np

from cdcr_ctl.discrepancy.keypoint_effects import EffectFit
from cdcr_ctl.discrepancy.keypoint_path import TIE_SE, registration_test
from cdcr_ctl.discrepancy.keypoint_rigid import frame_rigidity

N, NOISE = 600, 1.0


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _world(tilt_per_unit_rad: float, seed: int = 4):
    """Model tips of an arm's workspace (mm), a split variable in [0, 1] per row and logged tips:
    the model's tips turned about the base's y axis by 0.035 rad (2 deg) plus
    ``tilt_per_unit_rad`` x split, shifted (3, -2, 1) mm, tracker noise NOISE mm per axis."""
    rng = np.random.default_rng(seed)
    m = np.column_stack(
        [rng.uniform(-80, 80, N), rng.uniform(-80, 80, N), rng.uniform(150, 250, N)]
    )
    s = rng.uniform(0.0, 1.0, N)
    tip = np.array(
        [_rot_y(0.035 + tilt_per_unit_rad * si) @ mi for mi, si in zip(m, s, strict=True)]
    )
    tip += np.array([3.0, -2.0, 1.0]) + rng.normal(0.0, NOISE, (N, 3))
    fit = np.arange(N) < int(0.7 * N)
    return m, tip, fit, ~fit, s


def test_a_frame_fixed_in_the_lab_is_rigid_and_a_pose_dependent_tilt_is_not():
    """Fixed frame: the halves' frames differ by their estimation noise only (6 parameters from
    210 rows each: the other half's frame costs ~2 x 6 x 3 sigma^2 / 210 ~ 0.2 mm^2 at most),
    far below the noise floor 3 sigma^2 = 3 mm^2. A tilt of 0.04 rad per unit of the split
    (halves' mean tilts 0.02 rad apart: ~4 mm at 200 mm reach, ~16 mm^2 of squared error per
    row) is beyond the floor and beyond 2 SE."""
    m, tip, fit, held, s = _world(0.0)
    r = frame_rigidity(m, tip, fit, held, s, NOISE, TIE_SE)
    assert r.rigid and abs(r.cost_mm2) < 0.5, r
    assert r.n_fit == (210, 210) and r.n_held == 180
    m, tip, fit, held, s = _world(0.04)
    r = frame_rigidity(m, tip, fit, held, s, NOISE, TIE_SE)
    assert not r.rigid and r.cost_mm2 > 8.0 and r.cost_mm2 > TIE_SE * r.se_mm2, r
    assert "NOT ONE FRAME" in r.line("how far gravity moves the tip")


def _fit(name, err2, shrink=0.8, tips=None):
    return EffectFit(name, [], [], 1.0, shrink, 0.0, err2_heldout=err2, tips_full=tips)


def test_a_tie_goes_to_the_rival_only_when_registration_is_not_one_frame():
    """The rival X's tips are the config's plus a sag proportional to the split; the logged tips
    are X's with the frame error of :func:`_world`. Registration alone (on the config's tips)
    absorbs the sag only as a pose-dependent tilt: X is named. A fixed frame (no sag in the
    log, the config's tips logged through the frame): nothing is named by this test."""
    m, tip, fit, held, s = _world(0.0)
    sag = np.outer(s, [-6.0, 0.0, 0.0])  # X's extra droop: 6 mm where the split is largest
    rows = [np.arange(N)]
    err = np.ones(int(held.sum()))
    x = _fit("gravity", err, tips=[m + sag])
    reg = _fit("registration", err + 0.1)
    third = _fit("routing", err + 50.0, shrink=0.1)
    ranked = [x, reg, third]
    # the log: X's tips through the fixed frame, so registration alone must tilt with the sag
    logged = tip + sag @ _rot_y(0.035).T
    winner, lines = registration_test(ranked, x, reg, None, (m, logged, fit, held), rows, NOISE)
    assert winner is x and "NOT ONE FRAME" in lines[0], lines
    # a log of the config's tips through the frame alone: registration is one frame, no winner
    winner, lines = registration_test(ranked, x, reg, None, (m, tip, fit, held), rows, NOISE)
    assert winner is None and "one frame fits both halves" in lines[0], lines
