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

from cdcr_ctl.firstuse import first_use

#: The package's public names and the modules defining them, imported on first use
#: (:mod:`cdcr_ctl.firstuse`): ``cdcr_ctl.model.ujoint`` or ``.vertebra`` (what the config's design
#: checks import) no longer pays for the disk robot's chain and scipy.integrate.
LAZY = {
    "ActuatorEffect": "cdcr_ctl.model.params",
    "CCDiskModel": "cdcr_ctl.model.compensation",
    "CableParams": "cdcr_ctl.model.params",
    "CompensationState": "cdcr_ctl.model.compensation",
    "Compensator": "cdcr_ctl.model.compensation",
    "Effects": "cdcr_ctl.model.params",
    "ForceTransfer": "cdcr_ctl.model.transfer",
    "ForwardModel": "cdcr_ctl.model.forward",
    "ForwardResult": "cdcr_ctl.model.forward",
    "ForwardStepper": "cdcr_ctl.model.forward",
    "FrictionState": "cdcr_ctl.model.friction",
    "PulleyParams": "cdcr_ctl.model.params",
    "Replay": "cdcr_ctl.model.forward",
    "RobotParams": "cdcr_ctl.model.params",
    "SegmentParams": "cdcr_ctl.model.params",
    "Transfer": "cdcr_ctl.model.transfer",
    "replay": "cdcr_ctl.model.forward",
}
__getattr__ = first_use(globals(), LAZY)

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
