"""The BLAS thread policy (cdcr_ctl/blas.py): one thread for numpy's BLAS and scipy's once
cdcr_ctl is imported, whichever of numpy, scipy and cdcr_ctl came first, in the process and in
the processes it starts; an explicit OPENBLAS_NUM_THREADS is left alone; cdcr_ctl itself loads
no BLAS."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

#: Import orders: numpy (and its OpenBLAS) first as pytest or a notebook may do, scipy's own
#: OpenBLAS (scipy.linalg) before or after the package, the package first.
ORDERS = {
    "numpy_first": ("numpy", "cdcr_ctl", "scipy.linalg"),
    "numpy_scipy_first": ("numpy", "scipy.linalg", "cdcr_ctl"),
    "package_first": ("cdcr_ctl", "numpy", "scipy.linalg"),
    "package_then_scipy": ("cdcr_ctl", "scipy.optimize"),
}

REPORT = (
    "from threadpoolctl import threadpool_info\n"
    "blas = [i for i in threadpool_info() if i['user_api'] == 'blas']\n"
    "assert len(blas) >= 2, blas\n"  # numpy's and scipy's
    "print(sorted({i['num_threads'] for i in blas}))\n"
)


def _run(code: str, env_value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if env_value is not None:
        env["OPENBLAS_NUM_THREADS"] = env_value
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return out.stdout.strip()


def _probe(order: tuple[str, ...]) -> str:
    return "".join(f"import {m}\n" for m in order) + REPORT


@pytest.mark.parametrize("order", ORDERS.values(), ids=ORDERS.keys())
def test_one_blas_thread_in_every_import_order(order):
    assert _run(_probe(order), None) == "[1]"


@pytest.mark.parametrize("order", ORDERS.values(), ids=ORDERS.keys())
def test_explicit_environment_is_respected(order):
    assert _run(_probe(order), "2") == "[2]"


def test_processes_started_by_the_package_get_one_thread_too():
    child = _probe(("numpy", "scipy.linalg"))  # no cdcr_ctl there: the environment does it
    code = (
        "import subprocess, sys\nimport cdcr_ctl\n"
        f"print(subprocess.run([sys.executable, '-c', {child!r}], capture_output=True, "
        "text=True, check=True).stdout.strip())\n"
    )
    assert _run(code, None) == "[1]"


def test_the_package_loads_no_blas():
    code = "import sys\nimport cdcr_ctl\nprint(sorted({'numpy', 'scipy'} & set(sys.modules)))\n"
    assert _run(code, None) == "[]"
