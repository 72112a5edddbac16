"""The robot models, pure physics: numpy/scipy only, no I/O, no clocks.

One package per design, beside the physics they share and the protocol the loop calls:

- :mod:`~cdcr_ctl.model.port`     ``RobotModelPort``, what every design's model offers the loop
- :mod:`~cdcr_ctl.model.shared`   capstan, disk-hole friction, lost motion
- :mod:`~cdcr_ctl.model.cc_disk`  constant-curvature disks (Qi et al. 2023)
- :mod:`~cdcr_ctl.model.ujoint`   universal-joint segments (Yang et al. 2022)
- :mod:`~cdcr_ctl.model.vertebra` ball-jointed vertebrae on an elastic rod

The names below (the disk design's) are importable from here, each on first use.
"""

from cdcr_ctl.firstuse import first_use

#: The package's public names and the modules defining them, imported on first use
#: (:mod:`cdcr_ctl.firstuse`): ``cdcr_ctl.model.ujoint`` or ``.vertebra`` (what the config's design
#: checks import) no longer pays for the disk robot's chain and scipy.integrate.
LAZY = {
    "ActuatorEffect": "cdcr_ctl.model.cc_disk.params",
    "CCDiskModel": "cdcr_ctl.model.cc_disk.compensation",
    "CableParams": "cdcr_ctl.model.cc_disk.params",
    "CompensationState": "cdcr_ctl.model.cc_disk.compensation",
    "Compensator": "cdcr_ctl.model.cc_disk.compensation",
    "Effects": "cdcr_ctl.model.cc_disk.params",
    "ForceTransfer": "cdcr_ctl.model.cc_disk.transfer",
    "ForwardModel": "cdcr_ctl.model.cc_disk.forward",
    "ForwardResult": "cdcr_ctl.model.cc_disk.forward",
    "ForwardStepper": "cdcr_ctl.model.cc_disk.forward",
    "FrictionState": "cdcr_ctl.model.shared.friction",
    "PulleyParams": "cdcr_ctl.model.cc_disk.params",
    "Replay": "cdcr_ctl.model.cc_disk.forward",
    "RobotParams": "cdcr_ctl.model.cc_disk.params",
    "SegmentParams": "cdcr_ctl.model.cc_disk.params",
    "Transfer": "cdcr_ctl.model.cc_disk.transfer",
    "replay": "cdcr_ctl.model.cc_disk.forward",
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
