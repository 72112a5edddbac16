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

import os

# One BLAS thread unless the environment says otherwise (set before numpy loads OpenBLAS). The
# controller's linear algebra is small; OpenBLAS's own threads only compete with the loop, the
# simulator and each other for the cores. Measured on this 2-core machine at load average 13:
# an SVD of the identification Jacobian's shape (1158 x 462) took 5.6 s with OpenBLAS's default
# threads and 0.35 s with one; that SVD (inside scipy's least_squares) was 87 of the first
# 99 s of the calibration fit of `cdcr-ctl experiments`.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
