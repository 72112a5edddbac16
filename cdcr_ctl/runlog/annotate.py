"""Add what was learnt after a run ended to its ``run.yaml`` (e.g. a faulted drive's own error
records, read by SDO once the run had already been closed by the fault)."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from cdcr_ctl.runlog.writer import RUN_YAML

#: How long :func:`annotate_when_ended` waits for the writer to record the end (s).
ENDED_TIMEOUT_S = 10.0


def annotate_run(run_dir: str | Path, key: str, value: Any) -> None:
    """Set top-level ``key`` of ``run_dir``/run.yaml to ``value`` (atomic replace)."""
    path = Path(run_dir) / RUN_YAML
    doc = yaml.safe_load(path.read_text()) or {}
    doc[key] = value
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".run.yaml.")
    try:
        with os.fdopen(fd, "w") as fh:
            yaml.safe_dump(doc, fh, sort_keys=False, allow_unicode=True)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def annotate_when_ended(
    run_dir: str | Path, key: str, value: Any, timeout_s: float = ENDED_TIMEOUT_S
) -> bool:
    """:func:`annotate_run` once run.yaml records the run's end (the writer finished); False
    when it did not within ``timeout_s`` (nothing written then)."""
    path = Path(run_dir) / RUN_YAML
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            if (yaml.safe_load(path.read_text()) or {}).get("ended"):
                annotate_run(run_dir, key, value)
                return True
        except (OSError, yaml.YAMLError):
            pass
        time.sleep(0.05)
    return False
