"""One BLAS thread per process, the project's only BLAS thread policy.

The controller's linear algebra is small (a 12 x 12 LU per Newton step, 3 x 3 rotations); the
one large product, the identification fit's SVDs inside scipy's ``least_squares`` (a Jacobian
of ~1158 x 462), ran 16x slower with OpenBLAS's default threads than with one on this 2-core
machine at load average 13 (5.6 s against 0.35 s): OpenBLAS's spinning threads compete with
the loop, the simulator, the truth worker and each other for the cores.

Why :func:`threadpoolctl.threadpool_limits` and not ``OPENBLAS_NUM_THREADS``: the variable acts
only if it is set before numpy loads OpenBLAS, which a test runner, a notebook or a caller that
imported numpy first has already done; threadpoolctl sets the thread count of the BLAS already
loaded, whenever it is called, but only the ones loaded by then. numpy and scipy each bring
their own OpenBLAS (``libscipy_openblas64_`` and ``libscipy_openblas``), and scipy's loads with
``scipy.linalg``: so this module imports both (there is then a BLAS of each to limit), and
:func:`one_blas_thread` runs on the package's import (``cdcr_ctl/__init__.py``). Every process
that imports ``cdcr_ctl`` (CLI, daemon, simulator, truth worker, pytest) runs BLAS on one thread
from then on. (Limiting numpy's alone left scipy's ``least_squares`` SVDs on two threads: the
experiments' fit took 149 s instead of 22 s at load average 7-10.) An ``OPENBLAS_NUM_THREADS``
the environment sets explicitly is the user's choice and is left alone.
"""

from __future__ import annotations

import os

import numpy  # noqa: F401  (loads numpy's OpenBLAS, so there is a library to limit)
import scipy.linalg  # noqa: F401  (loads scipy's own OpenBLAS, likewise)
from threadpoolctl import threadpool_limits

#: The environment variable that, when set, overrides :func:`one_blas_thread`.
ENV_OVERRIDE = "OPENBLAS_NUM_THREADS"


def one_blas_thread() -> None:
    """Limit the loaded BLAS to one thread for the rest of the process (unless
    ``OPENBLAS_NUM_THREADS`` is set: then OpenBLAS already took that count at load)."""
    if ENV_OVERRIDE in os.environ:
        return
    threadpool_limits(limits=1, user_api="blas")


__all__ = ["ENV_OVERRIDE", "one_blas_thread"]
