"""Identification of the force-transfer model's parameters from logged calibration runs.

Qi et al. 2023 eq. 38 fits the disk friction to load-cell tensions over a bending sweep; here the
same sweep (:mod:`.sweep`) also identifies the cable stiffness EA, the backbone EI, the
pretensions and the pulley friction, each from the signal that shows it (:mod:`.parameters`),
by one errors-in-variables least-squares problem over the quasi-static dwells of the log
(:mod:`.dwell`, :mod:`.estimator`). :mod:`.pipeline` goes from run directories to a YAML overlay
for the rig config; :mod:`.plots` and :mod:`.figures` draw the fit quality and the experiments.
Nothing here reads a simulator's truth: only the controller's rig config and the logs.

Importing the package imports none of its modules: a process that needs one of them (the
discrepancy analysis reads keypoint logs with :mod:`.keypoints`; ``cdcr-ctl experiments`` draws
with :mod:`.figures`) does not pay for the others (the estimator's scipy.stats is ~0.8 s of CPU).
The public names below are still the package's attributes: their module is imported on their
first use (:func:`__getattr__`). Code of the package imports them from their modules.
"""

from __future__ import annotations

from typing import Any

#: The package's public names, by the module that defines them (imported on first use).
_DWELL_NAMES = ("DwellPoint", "extract_dwells")
_ESTIMATOR_NAMES = ("Estimate", "FitOptions", "Identification", "identify")
_PARAMETER_NAMES = ("FitParameter", "NotIdentified", "plan_parameters")
_PIPELINE_NAMES = ("identify_runs", "overlay_text", "report_dict", "summary_table")
_SWEEP_NAMES = ("CalibrationSweep", "SweepSpec", "calibration_sweep")


def __getattr__(name: str) -> Any:
    """A public name of the package from its module (imported now, once; the name is then a
    plain attribute of the package)."""
    if name in _DWELL_NAMES:
        from cdcr_ctl.identify import dwell as module
    elif name in _ESTIMATOR_NAMES:
        from cdcr_ctl.identify import estimator as module
    elif name in _PARAMETER_NAMES:
        from cdcr_ctl.identify import parameters as module
    elif name in _PIPELINE_NAMES:
        from cdcr_ctl.identify import pipeline as module
    elif name in _SWEEP_NAMES:
        from cdcr_ctl.identify import sweep as module
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(module, name)
    globals()[name] = value
    return value


__all__ = [
    "CalibrationSweep",
    "DwellPoint",
    "Estimate",
    "FitOptions",
    "FitParameter",
    "Identification",
    "NotIdentified",
    "SweepSpec",
    "calibration_sweep",
    "extract_dwells",
    "identify",
    "identify_runs",
    "overlay_text",
    "plan_parameters",
    "report_dict",
    "summary_table",
]
