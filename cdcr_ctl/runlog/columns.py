"""Column names of ``samples.csv``: one place for the writer, the reader and the plots.

Units are in the names. Segments ``i`` and cables ``k`` are numbered from 1, in the order of
``robot.segments`` and ``robot.cables`` of the rig config.

==========================  ====  ==============================================================
column                      unit  meaning
==========================  ====  ==============================================================
``t_s``                     s     loop time of the cycle (monotonic clock, 0 at loop start)
``seg{i}_theta_cmd_rad``    rad   commanded bend angle θ_i of segment i
``seg{i}_phi_cmd_rad``      rad   commanded bending-plane direction φ_i of segment i
``cable{k}_q_nominal_mm``   mm    ideal inverse kinematics (no compensation), pulled in > 0
``cable{k}_q_cmd_mm``       mm    after compensation: what was sent to the drive
``cable{k}_q_act_mm``       mm    drive position feedback converted to mm
``cable{k}_tension_N``      N     load-cell tension of cable k
``tip_x_mm`` ...``_z_mm``   mm    tracked tip position in the robot base frame
==========================  ====  ==============================================================

Any other column is an *extra* (``cycle``, ``lateness_us``, ``event``, ``seg{i}_theta_est_rad``,
...). A missing measurement is an empty field.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence

#: The time column; the only column every run log must have.
TIME = "t_s"

#: Column groups a run log may carry (the reader reports which are present).
GROUP_PSI_CMD = "psi_cmd"
GROUP_Q_NOMINAL = "q_nominal"
GROUP_Q_CMD = "q_cmd"
GROUP_Q_ACT = "q_act"
GROUP_TENSION = "tension"
GROUP_TIP = "tip"
GROUPS = (GROUP_PSI_CMD, GROUP_Q_NOMINAL, GROUP_Q_CMD, GROUP_Q_ACT, GROUP_TENSION, GROUP_TIP)

#: Extra columns the control loop writes after the required ones.
LOOP_EXTRA_COLUMNS = ("cycle", "lateness_us", "event")

#: Extra columns known to hold text rather than numbers.
TEXT_COLUMNS = frozenset({"event"})

TIP_COLUMNS = ("tip_x_mm", "tip_y_mm", "tip_z_mm")


def t_cell(t_s: float) -> float:
    """The ``t_s`` of a loop row: the loop time (s) rounded to 1 us. One rule for the loop's
    row mapping and the writer process (which rounds what the loop hands over unrounded)."""
    return round(t_s, 6)


def lateness_cell_us(lateness_s: float) -> float:
    """The ``lateness_us`` of a loop row: the cycle's lateness (s) in us, rounded to 0.1 us."""
    return round(lateness_s * 1e6, 1)


_CABLE_KINDS = {
    GROUP_Q_NOMINAL: "q_nominal_mm",
    GROUP_Q_CMD: "q_cmd_mm",
    GROUP_Q_ACT: "q_act_mm",
    GROUP_TENSION: "tension_N",
}

_SEG_RE = re.compile(r"^seg([1-9][0-9]*)_(theta|phi)_cmd_rad$")
_CABLE_RE = re.compile(r"^cable([1-9][0-9]*)_(q_nominal_mm|q_cmd_mm|q_act_mm|tension_N)$")
_ANY_SEG_RE = re.compile(r"^seg([1-9][0-9]*)_")
_ANY_CABLE_RE = re.compile(r"^cable([1-9][0-9]*)_")


def theta_cmd(i: int) -> str:
    """Column of the commanded bend angle of segment ``i`` (1-based), rad."""
    return f"seg{i}_theta_cmd_rad"


def phi_cmd(i: int) -> str:
    """Column of the commanded bending direction of segment ``i`` (1-based), rad."""
    return f"seg{i}_phi_cmd_rad"


def cable_column(group: str, k: int) -> str:
    """Column of cable ``k`` (1-based) in ``group`` (one of the cable groups), e.g.
    ``cable_column("q_cmd", 2) == "cable2_q_cmd_mm"``."""
    return f"cable{k}_{_CABLE_KINDS[group]}"


def sample_columns(n_segments: int, n_cables: int, extra: Iterable[str] = ()) -> list[str]:
    """All columns of a run log, in file order.

    ``t_s``; θ/φ commands per segment; per cable group (nominal, command, actual, tension) the
    columns of cables 1..K; the tip; then ``extra`` in the order given. Raises ``ValueError`` for
    counts < 1 or an extra that repeats a column.
    """
    if n_segments < 1 or n_cables < 1:
        raise ValueError(f"need at least one segment and one cable (got {n_segments}, {n_cables})")
    cols = [TIME]
    for i in range(1, n_segments + 1):
        cols += [theta_cmd(i), phi_cmd(i)]
    for group in _CABLE_KINDS:
        cols += [cable_column(group, k) for k in range(1, n_cables + 1)]
    cols += list(TIP_COLUMNS)
    seen = set(cols)
    for name in extra:
        if name in seen or not name or "," in name or "\n" in name:
            raise ValueError(f"extra column {name!r} repeats a column or is not a plain name")
        seen.add(name)
        cols.append(name)
    return cols


def group_of(column: str) -> str | None:
    """The group a column belongs to, or None for ``t_s`` and extras."""
    if _SEG_RE.match(column):
        return GROUP_PSI_CMD
    m = _CABLE_RE.match(column)
    if m:
        return next(g for g, kind in _CABLE_KINDS.items() if kind == m.group(2))
    if column in TIP_COLUMNS:
        return GROUP_TIP
    return None


def counts_from_columns(columns: Sequence[str]) -> tuple[int, int]:
    """(segments, cables) implied by the highest ``seg{i}_`` and ``cable{k}_`` numbers (0: none)."""
    n_seg = max((int(m.group(1)) for c in columns if (m := _ANY_SEG_RE.match(c))), default=0)
    n_cab = max((int(m.group(1)) for c in columns if (m := _ANY_CABLE_RE.match(c))), default=0)
    return n_seg, n_cab
