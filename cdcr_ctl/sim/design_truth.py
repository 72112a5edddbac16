"""The truth of a rig's design: :func:`make_truth` picks constant-curvature disks
(:class:`~cdcr_ctl.sim.truth.TruthModel`), the universal-joint arm or the vertebra arm.

The shared base (state, world config, stepping) lives in :mod:`cdcr_ctl.sim.design_base`, which
the design truths import; this module imports them, so nothing here is imported back.
"""

from __future__ import annotations

from typing import Any

from cdcr_ctl.sim.design_base import DesignTruth, DesignTruthState, truth_rig_config
from cdcr_ctl.sim.simconfig import LoadedSim
from cdcr_ctl.sim.truth import TruthModel
from cdcr_ctl.sim.truth_ujoint import UJointTruth
from cdcr_ctl.sim.truth_vertebra import VertebraTruth

__all__ = ["DesignTruth", "DesignTruthState", "make_truth", "truth_rig_config"]


def make_truth(loaded: LoadedSim) -> Any:
    """The truth of the rig's design: :class:`~cdcr_ctl.sim.truth.TruthModel` (cc_disk),
    :class:`~cdcr_ctl.sim.truth_ujoint.UJointTruth` or
    :class:`~cdcr_ctl.sim.truth_vertebra.VertebraTruth`."""
    design = loaded.rig.design
    if design == "ujoint":
        return UJointTruth(loaded)
    if design == "vertebra":
        return VertebraTruth(loaded)
    return TruthModel(loaded)
