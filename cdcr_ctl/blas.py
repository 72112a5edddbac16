"""One BLAS thread per process, the project's only BLAS thread policy.

The controller's linear algebra is small (a 12 x 12 LU per Newton step, 3 x 3 rotations); the
one large product, the identification fit's SVDs inside scipy's ``least_squares`` (a Jacobian
of ~1158 x 462), ran 16x slower with OpenBLAS's default threads than with one on this 2-core
machine at load average 13 (5.6 s against 0.35 s): OpenBLAS's spinning threads compete with
the loop, the simulator, the truth worker and each other for the cores. (Limiting numpy's BLAS
alone left scipy's ``least_squares`` SVDs on two threads: the experiments' fit took 149 s
instead of 22 s at load average 7-10.)

numpy and scipy each bring their own OpenBLAS (``libscipy_openblas64_`` with numpy,
``libscipy_openblas`` with ``scipy.linalg``). An OpenBLAS takes its thread count from
``OPENBLAS_NUM_THREADS`` when it loads, and :func:`threadpoolctl.threadpool_limits` sets the
count of the ones already loaded. :func:`one_blas_thread` (run on the package's import,
``cdcr_ctl/__init__.py``) does both, so the order of imports does not matter:

- it sets ``OPENBLAS_NUM_THREADS=1`` in the environment: every OpenBLAS loaded later in this
  process (numpy and scipy imported after ``cdcr_ctl``) and in the processes it starts loads
  with one thread;
- if numpy is already imported (a test runner, a notebook or a caller that imported numpy
  first; scipy cannot be loaded without it), it limits the BLAS loaded so far with
  threadpoolctl.

It imports neither numpy nor scipy: a process of the package that needs no BLAS (the run-log
writer process, :mod:`cdcr_ctl.runlog.writer.child`) starts without them (numpy and
``scipy.linalg`` are ~0.35 s of CPU), and threadpoolctl (~15 ms) is imported only when there is
a loaded BLAS to limit. An ``OPENBLAS_NUM_THREADS`` the environment set before the package was
imported is the user's choice and is left alone (in the environment and in the loaded BLAS).
"""

from __future__ import annotations

import os
import sys

#: The environment variable that, when set before ``cdcr_ctl`` is imported, overrides
#: :func:`one_blas_thread`.
ENV_OVERRIDE = "OPENBLAS_NUM_THREADS"

#: The user's own ``OPENBLAS_NUM_THREADS`` (None: not set; then the policy sets it to 1).
_EXPLICIT = os.environ.get(ENV_OVERRIDE)


def one_blas_thread() -> None:
    """One BLAS thread for the rest of the process and the processes it starts (unless
    ``OPENBLAS_NUM_THREADS`` was set before the package's import: OpenBLAS takes that count)."""
    if _EXPLICIT is not None:
        return
    os.environ[ENV_OVERRIDE] = "1"  # every OpenBLAS loaded from now on
    if "numpy" in sys.modules:  # numpy (and maybe scipy) came first: its BLAS is loaded
        from threadpoolctl import threadpool_limits  # only when there is one to limit

        threadpool_limits(limits=1, user_api="blas")


__all__ = ["ENV_OVERRIDE", "one_blas_thread"]
