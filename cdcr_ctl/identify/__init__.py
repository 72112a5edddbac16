"""Identification of the force-transfer model's parameters from logged calibration runs.

Qi et al. 2023 eq. 38 fits the disk friction to load-cell tensions over a bending sweep; here the
same sweep (:mod:`.sweep`) also identifies the cable stiffness EA, the backbone EI, the
pretensions and the pulley friction, each from the signal that shows it (:mod:`.parameters`),
by one errors-in-variables least-squares problem over the quasi-static dwells of the log
(:mod:`.dwell`, :mod:`.estimator`). :mod:`.pipeline` goes from run directories to a YAML overlay
for the rig config; :mod:`.plots` and :mod:`.figures` draw the fit quality and the experiments.
Nothing here reads a simulator's truth: only the controller's rig config and the logs.
"""

from cdcr_ctl.identify.dwell import DwellPoint, extract_dwells
from cdcr_ctl.identify.estimator import Estimate, FitOptions, Identification, identify
from cdcr_ctl.identify.parameters import FitParameter, NotIdentified, plan_parameters
from cdcr_ctl.identify.pipeline import identify_runs, overlay_text, report_dict, summary_table
from cdcr_ctl.identify.sweep import CalibrationSweep, SweepSpec, calibration_sweep

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
