"""Model-discrepancy workflow: where model and measurement disagree, which physical
effect the model is missing, how much it explains.

:func:`~cdcr_ctl.discrepancy.workflow.analyse` runs it; :mod:`~cdcr_ctl.discrepancy.report`
writes the text report, the plots and the config fragment. The candidate effects are the pure
physics terms of :mod:`cdcr_ctl.model.cc_disk.effects`.
"""

from cdcr_ctl.discrepancy.workflow import DiscrepancyResult, analyse

__all__ = ["DiscrepancyResult", "analyse"]
