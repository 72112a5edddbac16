"""Pure physics of the constant-curvature disk robot (Qi et al. 2023).

numpy/scipy only: no I/O, no clocks.

Modules, one job each:

- :mod:`~cdcr_ctl.model.params`         frozen parameter dataclasses and the switchable ``Effects``
- :mod:`~cdcr_ctl.model.kinematics`     constant-curvature backbone, eq. 1-3, 6
- :mod:`~cdcr_ctl.model.routing`        cable displacements, paths through the disks, eq. 4-5, 20-22
- :mod:`~cdcr_ctl.model.statics`        virtual-work statics with coupling and gravity, eq. 7-15
- :mod:`~cdcr_ctl.model.friction`       disk-hole capstan and the stick/slide state, eq. 16-24
- :mod:`~cdcr_ctl.model.capstan`        improved capstan for the pulleys, eq. 25-32
- :mod:`~cdcr_ctl.model.elongation`     cable stretch from one integral, eq. 33-36
- :mod:`~cdcr_ctl.model.transfer`       the whole chain on plain floats (the fast path)
- :mod:`~cdcr_ctl.model.compensation`   q~ = q + delta, eq. 37, and the loop's ``CCDiskModel``
- :mod:`~cdcr_ctl.model.forward`        actuator displacements -> pose, the simulator's stepper
- :mod:`~cdcr_ctl.model.identification` least-squares fits with confidence intervals, eq. 38
"""

from cdcr_ctl.model.compensation import CCDiskModel, CompensationState, Compensator
from cdcr_ctl.model.forward import ForwardModel, ForwardResult, ForwardStepper, Replay, replay
from cdcr_ctl.model.friction import FrictionState
from cdcr_ctl.model.params import (
    ActuatorEffect,
    CableParams,
    Effects,
    PulleyParams,
    RobotParams,
    SegmentParams,
)
from cdcr_ctl.model.transfer import ForceTransfer, Transfer

__all__ = [
    "ActuatorEffect",
    "CCDiskModel",
    "CableParams",
    "CompensationState",
    "Compensator",
    "Effects",
    "ForceTransfer",
    "ForwardModel",
    "ForwardResult",
    "ForwardStepper",
    "FrictionState",
    "PulleyParams",
    "Replay",
    "RobotParams",
    "SegmentParams",
    "Transfer",
    "replay",
]
