"""The viewers' own code, run with Node: the npm packages of ``package.json`` installed by
``npm ci`` from ``package-lock.json`` into a cache directory keyed on the lock's hash (under the
system temporary directory; an install runs once per lock, later runs reuse it), and the
scripts of this directory run there.

:func:`node_dir` skips the calling test, saying why, when ``node`` or ``npm`` is not on PATH; an
``npm ci`` that fails (no registry) fails the test with npm's output.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import pytest

HERE = Path(__file__).resolve().parent
LOCK = HERE / "package-lock.json"
#: Where the installs are kept (one directory per lock hash); ``CDCR_NPM_CACHE`` overrides it.
CACHE = Path(os.environ.get("CDCR_NPM_CACHE", Path(tempfile.gettempdir()) / "cdcr-ctl-npm"))
NPM_CI = ["npm", "ci", "--ignore-scripts", "--no-audit", "--no-fund", "--loglevel=error"]


def node_dir() -> Path:
    """The directory holding ``node_modules`` for this lock, installed if need be."""
    missing = [tool for tool in ("node", "npm") if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"{' and '.join(missing)} not on PATH: the viewers' code runs on Node")
    digest = hashlib.sha256(LOCK.read_bytes() + (HERE / "package.json").read_bytes())
    target = CACHE / digest.hexdigest()[:16]
    if (target / "node_modules" / ".package-lock.json").is_file():
        return target
    CACHE.mkdir(parents=True, exist_ok=True)
    with open(CACHE / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # another test process may be installing the same
        if not (target / "node_modules" / ".package-lock.json").is_file():
            work = Path(tempfile.mkdtemp(prefix="install-", dir=CACHE))
            try:
                for name in ("package.json", "package-lock.json"):
                    shutil.copy(HERE / name, work / name)
                res = subprocess.run(NPM_CI, cwd=work, capture_output=True, text=True, timeout=300)
                assert res.returncode == 0, f"npm ci failed:\n{res.stdout}\n{res.stderr}"
                with contextlib.suppress(FileNotFoundError):
                    shutil.rmtree(target)
                work.rename(target)
            finally:
                shutil.rmtree(work, ignore_errors=True)
    return target


def _place(script: str) -> Path:
    """Copy ``script`` beside the installed packages (atomically: tests may run side by side)."""
    where = node_dir()
    fd, tmp = tempfile.mkstemp(prefix=f".{script}.", dir=where)
    os.close(fd)
    shutil.copy(HERE / script, tmp)
    os.replace(tmp, where / script)
    return where


def run_script(script: str, *args: str, timeout_s: float = 60.0) -> list[dict[str, Any]]:
    """Run ``script`` (a file of this directory) with Node beside the installed packages (ES
    modules resolve packages from the script's own directory) and return its JSON lines."""
    where = _place(script)
    res = subprocess.run(
        ["node", str(where / script), *args], capture_output=True, text=True, timeout=timeout_s
    )
    assert res.returncode == 0, f"node {script} failed:\n{res.stdout}\n{res.stderr}"
    return [json.loads(line) for line in res.stdout.splitlines() if line.strip()]


def start_script(script: str, *args: str) -> subprocess.Popen[str]:
    """Start ``script`` as :func:`run_script` does, without waiting (read its stdout after)."""
    where = _place(script)
    return subprocess.Popen(
        ["node", str(where / script), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def read_mcap(*paths: Path) -> dict[str, dict[str, Any]]:
    """What the official TypeScript readers (``McapIndexedReader`` and ``McapStreamReader`` of
    ``@mcap/core``) found in each file (``read_mcap.mjs``), by path."""
    return {r["path"]: r for r in run_script("read_mcap.mjs", *map(str, paths))}
