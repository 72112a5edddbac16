"""cdcr-ctl: controller daemon for cable-driven continuum robot (CDCR) rigs.

Layers (dependencies point down):

- ``cdcr_ctl.cli`` / ``cdcr_ctl.daemon``  application: command line, control socket, service
- ``cdcr_ctl.control``                     the real-time loop wiring model, drives and sensors
- ``cdcr_ctl.model``                       pure physics (numpy/scipy), no I/O, no clocks
- ``cdcr_ctl.drives`` / ``cdcr_ctl.sensors``  protocol code: counts and modes, newtons and mm
- ``cdcr_ctl.config``                      the validated YAML rig config
- ``cdcr_ctl.errors``                      one exception tree

``cdcr_ctl.sim`` stands beside them: simulated EPOS nodes, load cells, tracker and truth physics.
Production modules never import it.
"""

from cdcr_ctl.blas import one_blas_thread

# One BLAS thread in every process that imports the package, whatever was imported before or
# after it (why and how: cdcr_ctl/blas.py; numpy and scipy are not imported here).
one_blas_thread()

__version__ = "0.1.0"
