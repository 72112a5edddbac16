"""The BLAS thread policy (cdcr_ctl/blas.py): one thread once cdcr_ctl is imported, even when
numpy was loaded first, numpy's BLAS and scipy's; an explicit OPENBLAS_NUM_THREADS is left alone."""

from __future__ import annotations

import os
import subprocess
import sys

PROBE = (
    "import numpy\n"  # numpy (and OpenBLAS) first, as pytest or a notebook may do
    "import cdcr_ctl\n"
    "import scipy.optimize\n"  # scipy's own OpenBLAS too
    "from threadpoolctl import threadpool_info\n"
    "assert len([i for i in threadpool_info() if i['user_api'] == 'blas']) >= 2\n"
    "print(sorted({i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas'}))\n"
)


def _blas_threads(env_value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if env_value is not None:
        env["OPENBLAS_NUM_THREADS"] = env_value
    out = subprocess.run(
        [sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True
    )
    return out.stdout.strip()


def test_one_blas_thread_after_numpy_loaded_first():
    assert _blas_threads(None) == "[1]"


def test_explicit_environment_is_respected():
    assert _blas_threads("2") == "[2]"
