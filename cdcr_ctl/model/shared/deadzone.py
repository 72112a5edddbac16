"""Lost motion between drive and cable: the play operator and its rate-bounded inverse.

Plain floats, no I/O, no clocks. Units: mm of cable pulled in (the drive's position converted with
``counts_per_mm``), per cable, shape (K,).

The physics (Yang et al. 2022 eq. 13-17: a dead zone l_h at each reversal of a cable, the
hysteresis the cable path adds between drive and joint; here cable slack, sheath play and gear
backlash lumped into one play of total width b_k per cable). Forward, the *play operator*:

    y_k = clip(y_prev_k, x_k - b_k/2, x_k + b_k/2)                                     (P)

x the drive position, y the cable position; the cable follows only while the drive pushes on one
side of the play, and stands still while the drive crosses the gap after a reversal. Starting
centred (y = 0 at x = 0).

The inverse (Yang's dead-zone compensation, eq. 13 with l_h = b/2 on the side of the motion):
for a wanted cable path y(t) the drive must run ahead of it by half the play in the direction of
the last motion,

    x_k = y_k + c_k,   c_k -> +b_k/2 while y_k rises, -b_k/2 while it falls, kept while it holds
    (direction memory).                                                                (D)

Inserted into (P): while y rises with c = +b/2, clip(y_prev, y, y + b) = y (y_prev <= y), so the
cable follows exactly; likewise falling. At a reversal the exact inverse steps x by b in one
command, a velocity step the drive cannot follow (and the supervisor's velocity limit trips on).
:func:`dead_zone_inverse` therefore moves the pre-travel c by at most ``max_step_mm`` per call
(the control layer derives it from the cable velocity limit and the loop period), so the gap is
crossed in ceil(b / max_step) cycles, during which the cable stands still as it would anyway.
Limits: b = 0 gives x = y exactly; ``max_step_mm`` = inf gives the exact inverse of (P).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

#: Motion of the wanted cable position below this (mm) keeps the direction memory (a pose
#: that holds, or float noise of one; well below the smallest drive count of any config).
DIRECTION_EPS_MM = 1e-9


def play_forward(
    x_mm: Sequence[float], y_prev_mm: Sequence[float], half_mm: Sequence[float]
) -> list[float]:
    """Cable position through the play (P): min(max(y_prev, x - b/2), x + b/2), mm, per cable;
    ``half_mm`` the half widths b/2. Plain floats: the loop's few cables (for K = 3 a numpy
    clip costs about ten times as much)."""
    out = []
    for x, y, h in zip(x_mm, y_prev_mm, half_mm, strict=True):
        lo = x - h
        hi = x + h
        v = lo if y < lo else y
        out.append(hi if v > hi else v)
    return out


def dead_zone_inverse(
    y_mm: Sequence[float],
    state: list[list[float]],
    half_mm: Sequence[float],
    max_step_mm: float = math.inf,
    hysteresis_mm: float = 0.0,
) -> list[float]:
    """Drive positions (D) for the wanted cable positions ``y_mm`` (mm, per cable); ``half_mm``
    the half widths b/2. ``state`` rows [y_prev, c, y_ext, dir] per cable are updated in place
    (rows of two, [y_prev, c], are widened on first use; all zero at the start: centred): the
    wanted position of the last call, the pre-travel c (in [-b/2, b/2]), the extremum of the
    current direction and that direction. c moves towards its target by at most
    ``max_step_mm`` per call. Plain floats: the control loop's few cables (for K = 3 the same
    rule on numpy arrays costs about three times as much).

    Reversal rule with hysteresis h = max(``hysteresis_mm``, :data:`DIRECTION_EPS_MM`): the
    direction of motion ``dir`` (+1, -1, 0 before the first move) turns only once the wanted
    position has come back from its extremum in the current direction (``y_ext``) by more than
    h (a Schmitt trigger on y). A dip of the wanted position smaller than h (float noise, a
    sub-count wiggle of the compensation at a slow reversal) keeps the pre-travel where it is;
    a real reversal is declared h late, which costs at most h of cable motion. With h =
    :data:`DIRECTION_EPS_MM` the rule is the sample-to-sample one (y_ext is then y_prev).
    While y holds (|dy| <= eps) the pre-travel holds too, mid-crossing or not.
    """
    h = hysteresis_mm if hysteresis_mm > DIRECTION_EPS_MM else DIRECTION_EPS_MM
    out = []
    for k, y in enumerate(y_mm):
        row = state[k]
        if len(row) < 4:
            row.extend([row[0], 0.0][len(row) - 2 :])
        dy = y - row[0]
        c = row[1]
        y_ext, d = row[2], row[3]
        if d > 0.0:
            if y > y_ext:
                y_ext = y
            elif y < y_ext - h:
                d, y_ext = -1.0, y
        elif d < 0.0:
            if y < y_ext:
                y_ext = y
            elif y > y_ext + h:
                d, y_ext = 1.0, y
        elif y > y_ext + h:
            d, y_ext = 1.0, y
        elif y < y_ext - h:
            d, y_ext = -1.0, y
        row[2], row[3] = y_ext, d
        if -DIRECTION_EPS_MM <= dy <= DIRECTION_EPS_MM or d == 0.0:
            target = c
        else:
            target = half_mm[k] if d > 0.0 else -half_mm[k]
        d = target - c
        if d > max_step_mm:
            d = max_step_mm
        elif d < -max_step_mm:
            d = -max_step_mm
        c += d
        row[0] = y
        row[1] = c
        out.append(y + c)
    return out
