"""The truth of a rig's design: :func:`make_truth` builds the simulated world the design
registry names for it (:attr:`~cdcr_ctl.config.registry.Design.truth`): constant-curvature disks
(:class:`~cdcr_ctl.sim.truth.TruthModel`), the universal-joint arm
(:class:`~cdcr_ctl.sim.truth_ujoint.UJointTruth`) or the vertebra arm
(:class:`~cdcr_ctl.sim.truth_vertebra.VertebraTruth`).

The shared base (state, world config, stepping) lives in :mod:`cdcr_ctl.sim.design_base`, which
the design truths import; this module imports them by the registry's names, so nothing here is
imported back.
"""

from __future__ import annotations

from typing import Any

from cdcr_ctl.config.registry import design_of, resolve
from cdcr_ctl.sim.design_base import DesignTruth, DesignTruthState, truth_rig_config
from cdcr_ctl.sim.simconfig import LoadedSim

__all__ = ["DesignTruth", "DesignTruthState", "make_truth", "truth_rig_config"]


def make_truth(loaded: LoadedSim) -> Any:
    """The truth of the rig's design: its registered truth class, given ``loaded``."""
    return resolve(design_of(loaded.rig.design).truth)(loaded)
