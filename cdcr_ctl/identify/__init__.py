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
first use (:mod:`cdcr_ctl.firstuse`). Code of the package imports them from their modules.
"""

from __future__ import annotations

from cdcr_ctl.firstuse import first_use

#: The package's public names -> the module that defines them (imported on first use).
LAZY = {
    **dict.fromkeys(("DwellPoint", "extract_dwells"), "cdcr_ctl.identify.dwell"),
    **dict.fromkeys(
        ("Estimate", "FitOptions", "Identification", "identify"), "cdcr_ctl.identify.estimator"
    ),
    **dict.fromkeys(
        ("FitParameter", "NotIdentified", "plan_parameters"), "cdcr_ctl.identify.parameters"
    ),
    **dict.fromkeys(
        ("identify_runs", "overlay_text", "report_dict", "summary_table"),
        "cdcr_ctl.identify.pipeline",
    ),
    **dict.fromkeys(
        ("CalibrationSweep", "SweepSpec", "calibration_sweep"), "cdcr_ctl.identify.sweep"
    ),
}
__getattr__ = first_use(globals(), LAZY)

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
