"""The constant-curvature disk design (Qi et al. 2023): ``design: cc_disk``.

numpy/scipy only: no I/O, no clocks. Modules, one job each:

- :mod:`~.params`         frozen parameter dataclasses and the switchable ``Effects``
- :mod:`~.kinematics`     constant-curvature backbone, eq. 1-3, 6
- :mod:`~.routing`        cable displacements, paths through the disks, eq. 4-5, 20-22
- :mod:`~.statics`        virtual-work statics with coupling and gravity, eq. 7-15
- :mod:`~.elongation`     cable stretch from one integral, eq. 33-36
- :mod:`~.tension_chain`, :mod:`~.transfer`  the whole chain on plain floats (the loop's path)
- :mod:`~.compensation`   q~ = q + delta, eq. 37, and the loop's ``CCDiskModel``
- :mod:`~.effect_spec`, :mod:`~.effect_terms`, :mod:`~.effects`, :mod:`~.transmission_effects`
  the effects a model may add (tip load, actuator scale, lost motion) and their fits
- :mod:`~.forward`        actuator displacements -> pose, the simulator's stepper
- :mod:`~.identification` least-squares fits with confidence intervals, eq. 38

The capstan, disk-hole friction and lost motion it uses are :mod:`cdcr_ctl.model.shared`.
"""
