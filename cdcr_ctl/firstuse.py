"""Package attributes imported on first use (a module ``__getattr__``, PEP 562).

A package whose ``__init__`` re-exported its heavy modules made every process that imports one
light module of it pay for all of them: the run-log writer process imported the reader (and with
it numpy and scipy) through ``cdcr_ctl.runlog``, ``cdcr-ctl status`` the estimator's scipy.stats
through ``cdcr_ctl.identify``. Such a package keeps its public names as a table, name -> the
module defining it (``LAZY``), and sets ``__getattr__ = first_use(globals(), LAZY)``: the module
is imported when the name is first read, and the name is then a plain attribute of the package.
Code inside the project imports from the defining modules; ``tests/structure/test_imports.py``
counts every ``LAZY`` entry as an import of the package, so layers and cycles are still checked.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def first_use(namespace: dict[str, Any], table: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for the package whose ``globals()`` is ``namespace``: the names
    of ``table`` (name -> defining module) from their modules, imported on first use."""

    def getattr_(name: str) -> Any:
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {namespace['__name__']!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    return getattr_


__all__ = ["first_use"]
