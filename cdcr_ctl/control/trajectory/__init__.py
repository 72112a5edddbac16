"""Trajectories: timed setpoints of segment bend θ_i and bending direction φ_i (rad).

- :mod:`.core`: the :class:`Trajectory` (validation, sampling/interpolation in the bending
  vector, Qi et al. 2023 §2) and its constants;
- :mod:`.files`: CSV/YAML files and request rows -> validated trajectories;
- :mod:`.builders`: the papers' built-in trajectories (Qi et al. 2023 §5.1), moves and lead-ins.
"""

from cdcr_ctl.control.trajectory.builders import (
    BUILTINS,
    _grid,
    _positive,
    _smooth_ramp,
    go_and_return,
    move,
    planar_bend,
    random_smooth,
    spatial_circle,
    with_lead_in,
)
from cdcr_ctl.control.trajectory.core import (
    _RATE_RTOL,
    BUILTIN_DT_S,
    LEAD_IN_SPEED_RAD_S,
    LIST_SAMPLES,
    QI2023_BEND_RATE_RAD_S,
    Locator,
    Trajectory,
    _per_segment,
    _sample_locator,
    _wrap,
    bend_vectors,
    psi_from_vectors,
)
from cdcr_ctl.control.trajectory.files import (
    _CSV_NUMBER,
    _csv_header,
    _float,
    _read_text,
    _rows_locator,
    _yaml_node_line,
    from_samples,
    load_csv,
    load_trajectory,
    load_yaml,
)

__all__ = [
    "BUILTINS",
    "BUILTIN_DT_S",
    "LEAD_IN_SPEED_RAD_S",
    "LIST_SAMPLES",
    "QI2023_BEND_RATE_RAD_S",
    "_CSV_NUMBER",
    "_RATE_RTOL",
    "Locator",
    "Trajectory",
    "_csv_header",
    "_float",
    "_grid",
    "_per_segment",
    "_positive",
    "_read_text",
    "_rows_locator",
    "_sample_locator",
    "_smooth_ramp",
    "_wrap",
    "_yaml_node_line",
    "bend_vectors",
    "from_samples",
    "go_and_return",
    "load_csv",
    "load_trajectory",
    "load_yaml",
    "move",
    "planar_bend",
    "psi_from_vectors",
    "random_smooth",
    "spatial_circle",
    "with_lead_in",
]
